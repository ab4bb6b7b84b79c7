"""Occupancy grids: the true grid rasterised from a scenario, and a map the robot builds from its LiDAR.

Two grids share one geometry (`GridGeometry`, 0.05 m square cells over the scenario bounds):

- `build_grid(scenario)` rasterises `Scenario.solid_shapes()` (yawed boxes, cylinders) exactly: a cell is
  *occupied* when its centre lies within half a cell of a shape (so thin shapes are never lost) and
  *blocked* when its centre lies within the robot radius + a margin of a shape or of the bounds — the
  classic configuration-space inflation that lets a planner treat the robot as a point.
- `LidarMap` is the explorer's map (unknown / free / occupied). Each scan is cast into the grid, vectorised
  over the cells in range: a cell nearer than both rays bracketing its bearing becomes free (the wedges
  between rays, so no specks stay unknown between diverging rays), the cell where a ray ends becomes
  occupied. The world is static, so an occupied cell never turns free again.

Cells are indexed `(row, col)` = `(iy, ix)`; row 0 is the southern edge (`y = bounds.y[0]`).
Reference: H. Moravec and A. Elfes, "High resolution maps from wide angle sonar", ICRA 1985 (occupancy
grids); T. Lozano-Pérez, "Spatial planning: a configuration space approach", 1983 (inflation).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import TYPE_CHECKING, ClassVar, Protocol

import numpy as np

from llmnav.core.robot_specs import ROBOT_SPECS
from llmnav.errors import BadInputError
from llmnav.mapping.nearest import inside, nearest_within, reach_cells, within

if TYPE_CHECKING:
    from llmnav.core.geometry import Pose2D
    from llmnav.core.robot_specs import RobotSpec
    from llmnav.world.scenario import Bounds, Scenario, Shape

Cell = tuple[int, int]  # (row, col)


@dataclass(frozen=True)
class GridConfig:
    """How the true occupancy grid is built."""

    resolution_m: float = 0.05  # [m] cell side
    margin_m: float = 0.10  # [m] clearance kept beyond the robot radius (controller slack)


# [m] clearances a planner falls back to when none of its own fits (a doorway of the robot's width + 0.3 m
# leaves 0.15 m a side): the leg check and the collision monitor still keep the robot off the frame.
NARROW_MARGINS_M = (0.05, 0.02)


def margins_from(margin_m: float) -> tuple[float, ...]:
    """`margin_m` [m], then the narrower fallbacks below it, in the order a planner should try them."""
    return (margin_m, *(m for m in NARROW_MARGINS_M if m < margin_m))


@dataclass(frozen=True)
class GridGeometry:
    """Where the cells are: origin is the south-west corner of cell (0, 0)."""

    origin_x: float  # [m]
    origin_y: float  # [m]
    resolution: float  # [m] cell side
    rows: int
    cols: int

    @classmethod
    def from_bounds(cls, bounds: Bounds, resolution_m: float) -> GridGeometry:
        """Cover the scenario bounds with square cells."""
        if resolution_m <= 0:
            raise BadInputError(f"grid resolution must be positive, got {resolution_m} m")
        cols = max(1, math.ceil((bounds.x[1] - bounds.x[0]) / resolution_m - 1e-9))
        rows = max(1, math.ceil((bounds.y[1] - bounds.y[0]) / resolution_m - 1e-9))
        return cls(bounds.x[0], bounds.y[0], resolution_m, rows, cols)

    @property
    def shape(self) -> tuple[int, int]:
        """(rows, cols) of arrays on this geometry."""
        return (self.rows, self.cols)

    def world_to_cell(self, x: float, y: float) -> Cell:
        """The cell containing a point (may lie outside the grid; check with `contains`)."""
        return (
            math.floor((y - self.origin_y) / self.resolution),
            math.floor((x - self.origin_x) / self.resolution),
        )

    def cell_to_world(self, row: int, col: int) -> tuple[float, float]:
        """Centre [m] of a cell."""
        return (
            self.origin_x + (col + 0.5) * self.resolution,
            self.origin_y + (row + 0.5) * self.resolution,
        )

    def contains(self, cell: Cell) -> bool:
        """Whether a cell index lies inside the grid."""
        return 0 <= cell[0] < self.rows and 0 <= cell[1] < self.cols

    def world_to_cells(self, xs: np.ndarray, ys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Vectorised `world_to_cell`: (rows, cols) integer arrays."""
        rows = np.floor((ys - self.origin_y) / self.resolution).astype(np.int64)
        cols = np.floor((xs - self.origin_x) / self.resolution).astype(np.int64)
        return rows, cols

    def centres(self, rows: slice = slice(None), cols: slice = slice(None)) -> tuple[np.ndarray, np.ndarray]:
        """Cell-centre coordinates (xs, ys) [m] of a window of the grid, each of the window's shape."""
        row_idx = np.arange(self.rows)[rows]
        col_idx = np.arange(self.cols)[cols]
        xs = self.origin_x + (col_idx + 0.5) * self.resolution
        ys = self.origin_y + (row_idx + 0.5) * self.resolution
        grid_x, grid_y = np.meshgrid(xs, ys)
        return grid_x, grid_y


@dataclass
class OccupancyGrid:
    """The true grid of a scenario: `occupied` = solid footprints; `blocked` = robot centre may not be."""

    geometry: GridGeometry
    occupied: np.ndarray  # bool [rows, cols]
    blocked: np.ndarray  # bool [rows, cols], occupied inflated by `inflation_m` (and the bounds)
    inflation_m: float  # [m] robot radius + margin

    def is_free(self, x: float, y: float) -> bool:
        """Whether the robot centre may stand at (x, y); never at a point no cell index can hold."""
        try:
            cell = self.geometry.world_to_cell(x, y)
        except (OverflowError, ValueError):  # 1e308 / resolution is inf, floor(NaN) raises
            return False
        return self.geometry.contains(cell) and not bool(self.blocked[cell])


def shape_distance(shape: Shape, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    """Vectorised `Shape.distance_to`: distance [m] from points to the footprint (0 inside)."""
    dx, dy = xs - shape.center[0], ys - shape.center[1]
    if shape.shape == "cylinder":
        assert shape.radius is not None
        return np.maximum(np.hypot(dx, dy) - shape.radius, 0.0)
    assert shape.size is not None
    cos_yaw, sin_yaw = math.cos(shape.yaw), math.sin(shape.yaw)
    # Rotate the offsets into the box frame (by -yaw).
    local_x = cos_yaw * dx + sin_yaw * dy
    local_y = -sin_yaw * dx + cos_yaw * dy
    out_x = np.maximum(np.abs(local_x) - shape.size[0] / 2, 0.0)
    out_y = np.maximum(np.abs(local_y) - shape.size[1] / 2, 0.0)
    return np.hypot(out_x, out_y)


def _mark_shape(mask: np.ndarray, geometry: GridGeometry, shape: Shape, within_m: float) -> None:
    """Set cells whose centre lies within `within_m` of the shape (only the shape's window is evaluated)."""
    half_x, half_y = shape.half_extents()
    reach_x, reach_y = half_x + within_m, half_y + within_m
    res = geometry.resolution
    col0 = max(0, math.floor((shape.center[0] - reach_x - geometry.origin_x) / res))
    col1 = min(geometry.cols, math.ceil((shape.center[0] + reach_x - geometry.origin_x) / res) + 1)
    row0 = max(0, math.floor((shape.center[1] - reach_y - geometry.origin_y) / res))
    row1 = min(geometry.rows, math.ceil((shape.center[1] + reach_y - geometry.origin_y) / res) + 1)
    if col0 >= col1 or row0 >= row1:
        return
    xs, ys = geometry.centres(slice(row0, row1), slice(col0, col1))
    mask[row0:row1, col0:col1] |= shape_distance(shape, xs, ys) <= within_m


def build_grid(
    scenario: Scenario, *, robot: RobotSpec | None = None, config: GridConfig | None = None
) -> OccupancyGrid:
    """Rasterise a scenario's solid shapes; inflate them (and the bounds) by robot radius + margin.

    `robot` defaults to the scenario's robot model. Shapes whose bottom is above the robot's height
    (signs hung on walls) are left out: the robot passes beneath them.
    """
    config = config or GridConfig()
    robot = robot or ROBOT_SPECS[scenario.robot]
    geometry = GridGeometry.from_bounds(scenario.bounds, config.resolution_m)
    inflation = robot.radius_m + config.margin_m
    occupied = np.zeros(geometry.shape, dtype=bool)
    blocked = np.zeros(geometry.shape, dtype=bool)
    for shape in scenario.solid_shapes():
        if shape.z >= robot.height_m:
            continue
        _mark_shape(occupied, geometry, shape, geometry.resolution / 2)
        _mark_shape(blocked, geometry, shape, inflation)
    blocked |= near_bounds(geometry, scenario.bounds, inflation)
    return OccupancyGrid(geometry, occupied, blocked, inflation)


def near_bounds(geometry: GridGeometry, bounds: Bounds, within_m: float) -> np.ndarray:
    """Cells whose centre lies closer than `within_m` to the bounds: beyond them counts as a wall.

    Read-only and shared: a planner asks for the same band at every decision.
    """
    return _near_bounds(geometry, (bounds.x[0], bounds.x[1]), (bounds.y[0], bounds.y[1]), within_m)


@lru_cache(maxsize=16)
def _near_bounds(geometry: GridGeometry, x: tuple[float, float], y: tuple[float, float], within_m: float) -> np.ndarray:
    xs, ys = geometry.centres()
    near_x = (xs - x[0] < within_m) | (x[1] - xs < within_m)
    near_y = (ys - y[0] < within_m) | (y[1] - ys < within_m)
    near = np.asarray(near_x | near_y)
    near.flags.writeable = False
    return near


def nearest_free_cell(blocked: np.ndarray, geometry: GridGeometry, x: float, y: float, reach_m: float) -> Cell | None:
    """The cell of (x, y) if free, else the free cell nearest to (x, y) within `reach_m` [m] (None: none).

    Lets a planner start from a pose that lies inside the inflation (the robot brushed past a corner).
    """
    cell = geometry.world_to_cell(x, y)
    if not geometry.contains(cell):
        return None
    if not blocked[cell]:
        return cell
    reach = math.ceil(reach_m / geometry.resolution)
    row0, col0 = max(0, cell[0] - reach), max(0, cell[1] - reach)
    row1, col1 = min(geometry.rows, cell[0] + reach + 1), min(geometry.cols, cell[1] + reach + 1)
    xs, ys = geometry.centres(slice(row0, row1), slice(col0, col1))
    distance = np.hypot(xs - x, ys - y)
    distance[blocked[row0:row1, col0:col1] | (distance > reach_m)] = np.inf
    if not np.isfinite(distance).any():
        return None
    r, c = np.unravel_index(int(np.argmin(distance)), distance.shape)
    return (row0 + int(r), col0 + int(c))


def inflate(mask: np.ndarray, radius_m: float, resolution_m: float) -> np.ndarray:
    """Cells whose centre lies within `radius_m` of a set cell's centre (exact Euclidean distance)."""
    return within(mask, radius_m, resolution_m)


class ScanLike(Protocol):
    """What `LidarMap.integrate` reads from a scan (llmnav.sim.sensors.LidarScan has these fields)."""

    angles: np.ndarray  # [rad] relative to the heading, CCW positive
    ranges: np.ndarray  # [m], np.inf where nothing was hit
    range_max: float  # [m]


class LidarMap:
    """A map built from the robot's own LiDAR: every cell unknown, free or occupied.

    The robot is assumed to know its pose (ground truth or good odometry); the map covers the same
    extent as the scenario bounds, which the explorer is allowed to know.
    """

    UNKNOWN: ClassVar[int] = -1
    FREE: ClassVar[int] = 0
    OCCUPIED: ClassVar[int] = 1

    def __init__(self, geometry: GridGeometry) -> None:
        self.geometry = geometry
        self.state = np.full(geometry.shape, self.UNKNOWN, dtype=np.int8)
        self.scans = 0
        # The state, reach [cells] and squared distances to not-free cells last computed (`not_free_within`).
        self._distance: tuple[np.ndarray, int, np.ndarray | None] | None = None

    def not_free_within(self, radius_m: float) -> np.ndarray:
        """Cells whose centre lies within `radius_m` of an occupied or unknown cell (`inflate` of them).

        The squared distances behind it are kept until the map changes: planners inflate the same map by
        several margins, and look again between scans.
        """
        resolution = self.geometry.resolution
        reach = reach_cells(radius_m, resolution)
        cached = self._distance
        if cached is None or cached[1] < reach or not np.array_equal(cached[0], self.state):
            not_free = self.state != self.FREE
            squared = nearest_within(not_free, reach)[0] if not_free.any() else None
            cached = (self.state.copy(), reach, squared)
            self._distance = cached
        squared = cached[2]
        if squared is None or radius_m < 0:
            return np.zeros(self.geometry.shape, dtype=bool)
        return inside(squared, radius_m, resolution)

    def integrate(self, pose: Pose2D, scan: ScanLike) -> None:
        """Add one scan taken at `pose` (LiDAR at the robot centre): free wedges, occupied end points.

        A cell is free when it lies inside the scan's field of view and nearer than *both* rays that
        bracket its bearing (less half a cell); taking the smaller of the two never frees space behind an
        obstacle's edge, and filling between rays leaves no unobserved specks far from the robot, which
        would otherwise show up as false frontiers. A ray that hit nothing proves free space up to the
        maximum range. The cell at each hit point becomes occupied.
        """
        angles = np.asarray(scan.angles, dtype=float)
        ranges = np.asarray(scan.ranges, dtype=float)
        if angles.size < 2:
            raise BadInputError("a LiDAR scan needs at least two rays")
        hit = np.isfinite(ranges) & (ranges < scan.range_max)
        half_cell = self.geometry.resolution / 2
        free_len = np.clip(np.where(hit, ranges - half_cell, scan.range_max), 0.0, scan.range_max)  # [m]

        # The window of cells the scan can reach.
        geometry = self.geometry
        reach = scan.range_max + geometry.resolution
        col0 = max(0, math.floor((pose.x - reach - geometry.origin_x) / geometry.resolution))
        col1 = min(geometry.cols, math.ceil((pose.x + reach - geometry.origin_x) / geometry.resolution) + 1)
        row0 = max(0, math.floor((pose.y - reach - geometry.origin_y) / geometry.resolution))
        row1 = min(geometry.rows, math.ceil((pose.y + reach - geometry.origin_y) / geometry.resolution) + 1)
        if col0 < col1 and row0 < row1:
            window = self.state[row0:row1, col0:col1]
            # Only unknown cells can change (occupied ones stay, free ones are free already), and only
            # those within the longest free ray: the trigonometry runs on them alone. Their offsets are
            # computed as `GridGeometry.centres` does, so every float is the same; a squared distance
            # with a margin far above rounding picks the candidates, the exact distance decides.
            dxs = geometry.origin_x + (np.arange(col0, col1) + 0.5) * geometry.resolution - pose.x
            dys = geometry.origin_y + (np.arange(row0, row1) + 0.5) * geometry.resolution - pose.y
            longest = float(free_len.max())
            candidate = dys[:, None] ** 2 + dxs[None, :] ** 2 <= (longest * (1.0 + 1e-9)) ** 2
            rows, cols = np.nonzero(candidate & (window == self.UNKNOWN))
            dx, dy = dxs[cols], dys[rows]
            distance = np.hypot(dx, dy)
            near = distance <= longest
            rows, cols, dx, dy, distance = rows[near], cols[near], dx[near], dy[near], distance[near]
            bearing = np.mod(np.arctan2(dy, dx) - pose.yaw - angles[0], 2.0 * math.pi)  # [rad] from ray 0
            relative = angles - angles[0]  # [rad] ascending from 0
            step = float(relative[1] - relative[0])
            full_circle = relative[-1] + step >= 2.0 * math.pi - 1e-6
            upper = np.searchsorted(relative, bearing, side="right")  # first ray beyond the bearing
            n = angles.size
            if full_circle:
                bound = np.minimum(free_len[(upper - 1) % n], free_len[upper % n])
                inside = np.ones_like(distance, dtype=bool)
            else:
                inside = bearing <= relative[-1]
                bound = np.minimum(free_len[np.clip(upper - 1, 0, n - 1)], free_len[np.clip(upper, 0, n - 1)])
            free = inside & (distance <= bound)
            window[rows[free], cols[free]] = self.FREE
            here = geometry.world_to_cell(pose.x, pose.y)
            if geometry.contains(here):  # the robot stands on free floor (a pose off the map frees nothing)
                self.state[here] = self.FREE

        self._occupy(pose, angles[hit], ranges[hit])
        self.scans += 1

    def mark_hits(self, pose: Pose2D, scan: ScanLike) -> None:
        """Mark the returns of a scan taken at `pose` occupied, freeing nothing.

        For a scanner below the LiDAR's plane: its rays pass under what stands higher up (a table top), so
        the free space it crosses proves nothing at the LiDAR's height; only what it hits is certain.
        """
        angles = np.asarray(scan.angles, dtype=float)
        ranges = np.asarray(scan.ranges, dtype=float)
        hit = np.isfinite(ranges) & np.isfinite(angles) & (ranges < scan.range_max)
        self._occupy(pose, angles[hit], ranges[hit])

    def _occupy(self, pose: Pose2D, angles: np.ndarray, ranges: np.ndarray) -> None:
        """Mark the cells of returns (`angles` [rad] from the heading, `ranges` [m]) seen from `pose` occupied."""
        geometry = self.geometry
        world_angles = angles + pose.yaw
        xs = pose.x + np.cos(world_angles) * ranges
        rows, cols = geometry.world_to_cells(xs, pose.y + np.sin(world_angles) * ranges)
        inside_grid = (rows >= 0) & (rows < geometry.rows) & (cols >= 0) & (cols < geometry.cols)
        self.state[rows[inside_grid], cols[inside_grid]] = self.OCCUPIED

    def mark_occupied(self, x: float, y: float, radius_m: float) -> None:
        """Mark a disc occupied (a bump into something the LiDAR cannot see)."""
        xs, ys = self.geometry.centres()
        self.state[np.hypot(xs - x, ys - y) <= radius_m] = self.OCCUPIED

    @property
    def free(self) -> np.ndarray:
        """Bool mask of known-free cells."""
        return np.asarray(self.state == self.FREE)

    @property
    def occupied(self) -> np.ndarray:
        """Bool mask of occupied cells."""
        return np.asarray(self.state == self.OCCUPIED)

    @property
    def unknown(self) -> np.ndarray:
        """Bool mask of cells never observed."""
        return np.asarray(self.state == self.UNKNOWN)
