"""Frontier detection on the robot's own LiDAR map, and the planning grid it explores on.

A *frontier cell* is a known-free cell 4-adjacent to an unknown one: across a shared edge, the only
neighbour a LiDAR ray can actually reach. (Diagonal contact also counts free cells whose unknown
neighbour lies behind a wall's corner: looking from there shows nothing new.) Frontier cells are
clustered 8-connected, and clusters smaller than a minimum are noise.

The planning grid of a robot that knows only its own map (`sensed_grid`) blocks occupied *and unknown*
cells, inflated alike: whatever hides in the unknown, the robot keeps the same clearance from it as from
a seen wall. So no frontier cell is free in that grid, and the place to look past a frontier from is a
free cell near it: `goal_cells` gives each free cell within reach of a frontier cell the cluster of its
nearest frontier cell.

Reference: B. Yamauchi, "A frontier-based approach for autonomous exploration", IEEE CIRA 1997.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from llmnav.mapping.grid import LidarMap, OccupancyGrid, near_bounds
from llmnav.mapping.nearest import dilate4, inside, label8, nearest_within, reach_cells

if TYPE_CHECKING:
    from llmnav.world.scenario import Bounds


def sensed_grid(lidar_map: LidarMap, bounds: Bounds, inflation_m: float) -> OccupancyGrid:
    """The planning grid of the robot's own map.

    Occupied and unknown cells and the world's extent are inflated by `inflation_m` [m] (the robot's
    radius plus its clearance).
    """
    geometry = lidar_map.geometry
    blocked = lidar_map.not_free_within(inflation_m)
    blocked |= near_bounds(geometry, bounds, inflation_m)
    return OccupancyGrid(geometry, lidar_map.occupied, blocked, inflation_m)


def frontier_clusters(lidar_map: LidarMap, min_cells: int, free: np.ndarray | None = None) -> np.ndarray:
    """Frontier cells labelled by cluster (0: no frontier, or a cluster under `min_cells` cells).

    `free` narrows the known-free cells that may be frontier cells (default: all of the map's).
    """
    known_free = lidar_map.free if free is None else free
    # Edge neighbours decide frontier status; clusters join across corners too (a diagonal run of
    # frontier cells is one opening).
    frontier = known_free & dilate4(lidar_map.unknown)
    labels, count = label8(frontier)
    if count == 0:
        return np.asarray(labels)
    big = np.bincount(labels.ravel()) >= min_cells
    big[0] = False
    return np.where(big[labels], labels, 0)


def goal_cells(labels: np.ndarray, grid: OccupancyGrid, reach_m: float) -> np.ndarray:
    """Free cells of `grid` within `reach_m` [m] of a labelled frontier cell.

    Each is labelled by the cluster of its nearest labelled frontier cell (0 elsewhere).
    """
    if not labels.any():
        return np.zeros_like(labels)
    resolution = grid.geometry.resolution
    squared, nearest = nearest_within(labels != 0, reach_cells(reach_m, resolution), carry=labels)
    assert nearest is not None
    return np.where(inside(squared, reach_m, resolution) & ~grid.blocked, nearest, 0)
