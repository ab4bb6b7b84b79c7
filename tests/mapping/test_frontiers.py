"""Frontier detection on a LiDAR map: edge neighbours only, small clusters dropped, goal cells by cluster."""

from __future__ import annotations

import numpy as np

from llmnav.mapping.frontiers import frontier_clusters, goal_cells, sensed_grid
from llmnav.mapping.grid import GridGeometry, LidarMap
from llmnav.world.scenario import Bounds


def lidar_map(rows: int = 20, cols: int = 20) -> LidarMap:
    return LidarMap(GridGeometry(0.0, 0.0, 0.05, rows, cols))


def test_a_free_cell_touching_the_unknown_only_at_a_corner_is_no_frontier() -> None:
    grid = lidar_map()
    grid.state[:, :] = LidarMap.OCCUPIED
    grid.state[5, 5] = LidarMap.FREE
    grid.state[6, 6] = LidarMap.UNKNOWN  # diagonal: behind a wall's corner
    assert not frontier_clusters(grid, min_cells=1).any()
    grid.state[5, 6] = LidarMap.UNKNOWN  # across an edge: a ray can reach it
    assert frontier_clusters(grid, min_cells=1)[5, 5] > 0


def test_small_clusters_are_noise_and_goals_belong_to_the_nearest_kept_cluster() -> None:
    grid = lidar_map()
    grid.state[:, :10] = LidarMap.FREE  # the west half is seen free, the east half unknown
    grid.state[15, 15:17] = LidarMap.FREE  # two seen cells out in the unknown: a second, small frontier
    labels = frontier_clusters(grid, min_cells=10)
    kept = np.unique(labels[labels > 0])
    assert len(kept) == 1 and labels[10, 9] == kept[0]  # the long edge along column 9
    assert not labels[15, 15:17].any()  # the small cluster is dropped
    bounds = Bounds(x=(0.0, 1.0), y=(0.0, 1.0))
    planning = sensed_grid(grid, bounds, inflation_m=0.1)
    goals = goal_cells(labels, planning, reach_m=0.3)
    assert goals.any() and set(np.unique(goals[goals > 0])) == {kept[0]}
    assert not (goals > 0)[planning.blocked].any()  # only cells the robot may stand on
