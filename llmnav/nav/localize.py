"""Scan-to-map localization: each LiDAR scan registered against the occupancy map built so far.

A SLAM front-end in the manner of Hector SLAM and Cartographer's local matcher, on the robot's own
`LidarMap`: the pose the planner believes is `correction ∘ odometry`, and each `update(odom, scan)`
re-estimates the correction (map ← odometry) from one scan.

1. The map's occupied cells give a distance field: for every cell, the distance [m] to the nearest
   occupied cell, cut at `field_reach_m` (`llmnav.mapping.nearest.nearest_within`; kept between scans
   and computed again only near cells that became occupied). A scan point farther than that from the map
   (new space, a box that appeared) is an outlier and pulls on nothing.
2. Correlative search (E. Olson, "Real-time correlative scan matching", ICRA 2009): every pose of a small
   lattice of (dx, dy, dyaw) around the odometry prediction (every second scan point) is scored by how
   near the points land to occupied cells; the best one seeds step 3. The lattice spans what odometry may
   have drifted since the last accepted match (±0.2 m and ±6° at least, wider after long turns and
   drives), which plain ICP from the prediction does not cover (measured: docs/localization.md).
3. Gauss-Newton on the bilinearly interpolated distance field (A. Fitzgibbon, "Robust registration of 2D
   and 3D point sets", 2003: ICP without correspondences; the bilinear map gradient as in S. Kohlbrecher
   et al., "A flexible and scalable SLAM system with full 3D motion estimation", 2011), damped so that a
   direction the scan does not constrain (a bare corridor) stays at the prediction.
4. A match is rejected, and the odometry prediction kept, when the scan has too few returns, the map too
   few occupied cells, too few points end near the map after matching, or the match lies beyond the
   lattice's reach (plus a little for step 3).

The localizer reads only the scan, the odometry and the map; ground truth never. Cost: about 2-3 ms of
CPU per 360-ray scan in the 20 m x 16 m factory (docs/localization.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from llmnav.core.geometry import Pose2D, wrap_angle
from llmnav.mapping.nearest import nearest_within

if TYPE_CHECKING:
    from llmnav.mapping.grid import LidarMap, ScanLike


@dataclass(frozen=True)
class LocalizerConfig:
    """Numbers of the scan matcher."""

    field_reach_m: float = 0.3  # [m] distance field cut-off: scan points farther from the map are outliers
    search_xy_m: float = 0.2  # [m] half-width of the correlative lattice in x and y, at least
    search_xy_step_cells: int = 2  # its spacing [cells of the map]: Gauss-Newton refines between them
    search_yaw_rad: float = math.radians(6.0)  # [rad] half-width in heading, at least
    search_yaw_step_rad: float = math.radians(2.0)  # [rad] its spacing
    # The lattice widens with the odometry since the last accepted match (what it may have drifted by: a few
    # per cent of track-width error on every turn, unequal wheels curving a straight run), up to a cap.
    xy_drift_per_m: float = 0.05  # [m/m] of distance driven
    yaw_drift_per_rad: float = 0.10  # [rad/rad] of turn
    yaw_drift_per_m: float = 0.02  # [rad/m] of distance driven
    search_xy_max_m: float = 0.3  # [m]
    search_yaw_max_rad: float = math.radians(20.0)  # [rad]
    lattice_stride: int = 2  # every n-th point scores the lattice (Gauss-Newton then uses all)
    hit_m: float = 0.10  # [m] a point this near an occupied cell counts as matched
    iterations: int = 8  # Gauss-Newton steps
    damping: float = 1.0  # [m^2 per point-equivalent] pulls unconstrained directions to the seed
    min_points: int = 30  # returns a scan needs to be matched
    min_map_cells: int = 50  # occupied cells the map needs before anything is matched to it
    min_matched: float = 0.5  # share of the scan's points that must end within `hit_m` of the map
    # A match farther from the prediction than the lattice reaches plus this is not believed
    jump_slack_m: float = 0.1  # [m]
    jump_slack_rad: float = math.radians(2.0)  # [rad]


@dataclass(frozen=True)
class Match:
    """What one `update` concluded."""

    pose: Pose2D  # the believed pose after the update [m, rad]
    accepted: bool  # the scan corrected the pose; False: the odometry prediction stands
    matched: float  # share of the scan's points within `hit_m` of the map (0 when not tried)
    points: int  # returns used
    reason: str  # "matched", or why the match was not believed

    def fields(self) -> dict[str, object]:
        """What a `localize` event records of the match (beside the believed pose)."""
        return {"accepted": self.accepted, "matched": round(self.matched, 3), "points": self.points} | {
            "reason": self.reason
        }


def compose(a: Pose2D, b: Pose2D) -> Pose2D:
    """The pose `b` (given in `a`'s frame) in the frame `a` is given in."""
    c, s = math.cos(a.yaw), math.sin(a.yaw)
    return Pose2D(a.x + c * b.x - s * b.y, a.y + s * b.x + c * b.y, wrap_angle(a.yaw + b.yaw))


def inverse(a: Pose2D) -> Pose2D:
    """The transform undoing `a` (composed with `a`, the identity)."""
    c, s = math.cos(a.yaw), math.sin(a.yaw)
    return Pose2D(-c * a.x - s * a.y, s * a.x - c * a.y, wrap_angle(-a.yaw))


class Localizer:
    """Keeps the correction map ← odometry; see the module docstring."""

    def __init__(self, config: LocalizerConfig | None = None) -> None:
        self.cfg = config or LocalizerConfig()
        self.correction = Pose2D(0.0, 0.0, 0.0)  # map ← odometry; the identity until a scan corrects it
        self._field: _DistanceField | None = None
        self._last_odom: Pose2D | None = None  # odometry at the previous update
        self._moved_m = 0.0  # [m] odometry distance since the last accepted match
        self._turned_rad = 0.0  # [rad] odometry turn since the last accepted match

    def pose(self, odom: Pose2D) -> Pose2D:
        """The believed pose for an odometry pose: correction ∘ odom."""
        return compose(self.correction, odom)

    def update(self, odom: Pose2D, scan: ScanLike, grid_map: LidarMap) -> Match:
        """Register `scan` (taken at odometry pose `odom`) against `grid_map`; the believed pose after it.

        Call it before the scan is integrated into the map: the scan is matched against what earlier scans
        built, then integrated at the pose this returns.
        """
        cfg = self.cfg
        predicted = self.pose(odom)
        if self._last_odom is not None:
            self._moved_m += self._last_odom.distance_to(odom.x, odom.y)
            self._turned_rad += abs(wrap_angle(odom.yaw - self._last_odom.yaw))
        self._last_odom = odom
        xy_m = min(cfg.search_xy_max_m, cfg.search_xy_m + cfg.xy_drift_per_m * self._moved_m)  # [m]
        yaw_rad = cfg.search_yaw_rad + cfg.yaw_drift_per_rad * self._turned_rad + cfg.yaw_drift_per_m * self._moved_m
        yaw_rad = min(cfg.search_yaw_max_rad, yaw_rad)  # [rad]
        angles = np.asarray(scan.angles, dtype=float)
        ranges = np.asarray(scan.ranges, dtype=float)
        hit = np.isfinite(ranges) & (ranges < scan.range_max)
        points = np.column_stack((np.cos(angles[hit]) * ranges[hit], np.sin(angles[hit]) * ranges[hit]))  # [m]
        count = len(points)
        if count < cfg.min_points:
            return Match(predicted, False, 0.0, count, f"{count} returns (fewer than {cfg.min_points})")
        occupied = grid_map.occupied
        if int(occupied.sum()) < cfg.min_map_cells:
            return Match(predicted, False, 0.0, count, "the map is still nearly empty")
        if self._field is None or self._field.values.shape != occupied.shape:
            self._field = _DistanceField.of(grid_map, cfg.field_reach_m)
        field = self._field
        field.refresh(occupied)
        seed = _correlative(field, points[:: cfg.lattice_stride], predicted, (xy_m, yaw_rad), cfg)
        refined = _gauss_newton(field, points, seed, cfg)
        matched = float(np.mean(field.at(_transform(points, refined)) <= cfg.hit_m))
        jump = math.hypot(refined.x - predicted.x, refined.y - predicted.y)
        turned = abs(wrap_angle(refined.yaw - predicted.yaw))
        if matched < cfg.min_matched:
            return Match(predicted, False, matched, count, f"{matched:.0%} of the points on the map")
        if jump > xy_m + cfg.jump_slack_m or turned > yaw_rad + cfg.jump_slack_rad:
            return Match(predicted, False, matched, count, f"a jump of {jump:.2f} m, {math.degrees(turned):.1f} deg")
        self.correction = compose(refined, inverse(odom))
        self._moved_m = self._turned_rad = 0.0
        return Match(refined, True, matched, count, "matched")


def _transform(points: np.ndarray, pose: Pose2D) -> np.ndarray:
    """Points [m] of the robot frame in the map frame, seen from `pose`."""
    c, s = math.cos(pose.yaw), math.sin(pose.yaw)
    return np.column_stack((pose.x + c * points[:, 0] - s * points[:, 1], pose.y + s * points[:, 0] + c * points[:, 1]))


@dataclass
class _DistanceField:
    """Distance [m] from each cell of the map to the nearest occupied cell, cut at the reach.

    Kept up to date between scans: the map's occupied cells only ever grow (the world is static), and a
    new one changes the field only within the reach of it, so only that part is computed again.
    """

    values: np.ndarray  # [m] [rows, cols] of the map
    seen: np.ndarray  # bool [rows, cols]: the occupied cells the values were computed from
    origin_x: float  # [m] centre of the map's cell (0, 0)
    origin_y: float  # [m]
    resolution: float  # [m]
    reach_m: float  # [m] the value where nothing occupied is near

    @classmethod
    def of(cls, grid_map: LidarMap, reach_m: float) -> _DistanceField:
        """The field of a map with nothing occupied yet (brought up to date by `refresh`)."""
        geometry = grid_map.geometry
        res = geometry.resolution
        values = np.full(geometry.shape, reach_m)
        seen = np.zeros(geometry.shape, dtype=bool)
        return cls(values, seen, geometry.origin_x + res / 2, geometry.origin_y + res / 2, res, reach_m)

    def refresh(self, occupied: np.ndarray) -> None:
        """Bring the field up to date with the map's occupied cells."""
        reach = math.ceil(self.reach_m / self.resolution)  # [cells]
        if (self.seen & ~occupied).any():  # a cell was cleared (never by `LidarMap`): start again
            self.seen[:] = False
            self.values[:] = self.reach_m
        rows, cols = np.nonzero(occupied & ~self.seen)
        if rows.size == 0:
            return
        height, width = occupied.shape
        # Cells within the reach of a new one change; their nearest occupied cells lie within twice it.
        inner = (max(0, rows.min() - reach), min(height, rows.max() + reach + 1))
        inner_c = (max(0, cols.min() - reach), min(width, cols.max() + reach + 1))
        outer = (max(0, inner[0] - reach), min(height, inner[1] + reach))
        outer_c = (max(0, inner_c[0] - reach), min(width, inner_c[1] + reach))
        squared, _ = nearest_within(occupied[outer[0] : outer[1], outer_c[0] : outer_c[1]], reach)
        part = squared[inner[0] - outer[0] : inner[1] - outer[0], inner_c[0] - outer_c[0] : inner_c[1] - outer_c[0]]
        self.values[inner[0] : inner[1], inner_c[0] : inner_c[1]] = np.minimum(
            np.sqrt(part.astype(float)) * self.resolution, self.reach_m
        )
        self.seen |= occupied

    def at(self, xy: np.ndarray) -> np.ndarray:
        """The field at the cell nearest each point (the reach outside the window)."""
        rows = np.rint((xy[..., 1] - self.origin_y) / self.resolution).astype(np.int64)
        cols = np.rint((xy[..., 0] - self.origin_x) / self.resolution).astype(np.int64)
        h, w = self.values.shape
        inside = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
        out = np.full(rows.shape, self.reach_m)
        out[inside] = self.values[rows[inside], cols[inside]]
        return out

    def interpolate(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Bilinear value [m] and gradient (d/dx, d/dy) [-] at each point; outside the window: reach, 0."""
        u = (xy[:, 0] - self.origin_x) / self.resolution
        v = (xy[:, 1] - self.origin_y) / self.resolution
        c0, r0 = np.floor(u).astype(np.int64), np.floor(v).astype(np.int64)
        a, b = u - c0, v - r0  # fractions across the column and the row
        h, w = self.values.shape
        inside = (r0 >= 0) & (r0 < h - 1) & (c0 >= 0) & (c0 < w - 1)
        value = np.full(len(xy), self.reach_m)
        grad_x, grad_y = np.zeros(len(xy)), np.zeros(len(xy))
        r, c, a, b = r0[inside], c0[inside], a[inside], b[inside]
        f00, f01 = self.values[r, c], self.values[r, c + 1]
        f10, f11 = self.values[r + 1, c], self.values[r + 1, c + 1]
        value[inside] = (1 - b) * ((1 - a) * f00 + a * f01) + b * ((1 - a) * f10 + a * f11)
        grad_x[inside] = ((1 - b) * (f01 - f00) + b * (f11 - f10)) / self.resolution
        grad_y[inside] = ((1 - a) * (f10 - f00) + a * (f11 - f01)) / self.resolution
        return value, grad_x, grad_y


def _correlative(
    field: _DistanceField, points: np.ndarray, predicted: Pose2D, window: tuple[float, float], cfg: LocalizerConfig
) -> Pose2D:
    """The lattice pose around `predicted` under which the most scan points land near the map.

    `window` is the lattice's half-width: in x and y [m], in heading [rad].

    Shifts are whole cells, so each heading's points are rounded to cells once and every shift is an
    integer offset into the field. Each point scores 1 - d / reach (d its field value), so near misses
    count a little; among equal scores the candidate nearest the prediction wins.
    """
    res = field.resolution
    n_yaw = round(window[1] / cfg.search_yaw_step_rad)
    step = cfg.search_xy_step_cells
    n_xy = round(window[0] / res / step) * step  # [cells]
    yaw_steps = np.arange(-n_yaw, n_yaw + 1) * cfg.search_yaw_step_rad  # [rad]
    shifts = np.arange(-n_xy, n_xy + 1, step)  # [cells]
    yaws = predicted.yaw + yaw_steps
    c, s = np.cos(yaws)[:, None], np.sin(yaws)[:, None]
    # [yaw, point] the cell of each point under each heading, in the field padded by the shifts
    cols = np.rint((predicted.x + c * points[:, 0] - s * points[:, 1] - field.origin_x) / res).astype(np.int64)
    rows = np.rint((predicted.y + s * points[:, 0] + c * points[:, 1] - field.origin_y) / res).astype(np.int64)
    padded = np.pad(field.values, n_xy, constant_values=field.reach_m)
    height, width = padded.shape
    rows, cols = rows + n_xy, cols + n_xy
    # a point off the window reads the sentinel appended last: the reach, whatever the shift
    inside = (rows >= n_xy) & (rows < height - n_xy) & (cols >= n_xy) & (cols < width - n_xy)
    flat = np.append(padded.ravel(), field.reach_m)
    offsets = (shifts[:, None] * width + shifts[None, :]).ravel()  # [shift] (row shift, column shift)
    index = np.where(inside[:, None, :], (rows * width + cols)[:, None, :] + offsets[None, :, None], flat.size - 1)
    values = flat[index]  # [yaw, shift, point]
    score = (1.0 - values / field.reach_m).sum(axis=-1)  # [yaw, shift]
    dr, dc = np.meshgrid(shifts, shifts, indexing="ij")
    distance = np.abs(yaw_steps)[:, None] / cfg.search_yaw_step_rad + np.hypot(dr, dc).ravel()[None, :] / step
    best = np.flatnonzero(score.ravel() == score.max())
    k = int(best[np.argmin(distance.ravel()[best])])
    i, j = divmod(k, offsets.size)
    return Pose2D(
        predicted.x + float(dc.ravel()[j]) * res, predicted.y + float(dr.ravel()[j]) * res, wrap_angle(float(yaws[i]))
    )


def _gauss_newton(field: _DistanceField, points: np.ndarray, seed: Pose2D, cfg: LocalizerConfig) -> Pose2D:
    """Minimise the sum of squared field values at the scan points, starting at `seed`.

    Points at the cut-off have a zero gradient and drop out by themselves (a truncated quadratic loss).
    The damping keeps the step small along whatever the scan leaves unconstrained.
    """
    x, y, yaw = seed.x, seed.y, seed.yaw
    for _ in range(cfg.iterations):
        c, s = math.cos(yaw), math.sin(yaw)
        px, py = points[:, 0], points[:, 1]
        world = np.column_stack((x + c * px - s * py, y + s * px + c * py))
        value, gx, gy = field.interpolate(world)
        near = value < field.reach_m
        if int(near.sum()) < cfg.min_points:
            break
        # d(world point)/d(yaw) = (-s px - c py, c px - s py)
        dyaw = gx * (-s * px - c * py) + gy * (c * px - s * py)
        jac = np.column_stack((gx, gy, dyaw))[near]
        res = value[near]
        hessian = jac.T @ jac + cfg.damping * np.diag([1.0, 1.0, 1.0])
        step = np.linalg.solve(hessian, -(jac.T @ res))
        x, y, yaw = x + float(step[0]), y + float(step[1]), yaw + float(step[2])
        if abs(step[0]) + abs(step[1]) < 1e-4 and abs(step[2]) < 1e-4:
            break
    return Pose2D(x, y, wrap_angle(yaw))
