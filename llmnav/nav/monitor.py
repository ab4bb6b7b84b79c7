"""Collision monitor: the last check between any motion command and the wheels, on every control step.

Modelled on nav2's `collision_monitor`: it reads raw range data (never a map, never the physics engine's
truth) and judges every velocity command the motion layer is about to apply, whatever produced it — a
straight leg, a turn, an arc, a 50 Hz velocity tick.

Sources: every `RangeSource` (the planar LiDAR, and a low scanner that sees what lies below the LiDAR
plane) is re-cast at most every `scan_period_s` of sim time, out to `reach_m`; its returns are kept in
the odometry frame of the moment they were taken and carried into the robot's present frame with the
odometry since then (over a tenth of a second odometry drift is far below a millimetre).

The zone is the robot's real footprint (its disc, or its rectangle) grown by `margin_m`, swept along the
commanded motion for as long as the robot needs to stop from it: one control step at the commanded twist
plus the braking time at the robot's acceleration limits. This is nav2's "approach" behaviour: the
command is scaled down (its curvature kept) until the robot can still stop before touching anything, so
the robot slows as it closes in, and stops outright when even a creep would reach an obstacle. A return
the footprint already overlaps but moves away from never holds the robot (it may back out of a tight
spot). A box base sweeps its corners while turning in place, so turns are judged the same way; a round
base sweeps nothing new turning and is never held for a turn.

A stop is reported (`MonitorStop`: source, distance, the blocking returns) so the motion ends and the
planner can recover; slowing down is not an event. Cost: see `python -m bench guard` (target 0.2 ms per
control step).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol

import numpy as np

from llmnav.errors import SensorFailure, one_line

if TYPE_CHECKING:
    from llmnav.core.geometry import Pose2D
    from llmnav.core.robot_specs import RobotSpec
    from llmnav.sim.sensors import LidarScan

SAMPLE_STEP_M = 0.01  # [m] spacing of the footprint poses swept along a motion
SAMPLE_STEP_RAD = math.radians(1.0)  # [rad] ... and of the headings swept along a turn
CREEP_FRACTION = 0.03  # below this share of the command the robot is stopped rather than crept forward
CLOSING_EPS_M = 1e-6  # [m] a clearance must shrink by more than this to count as closing in
_EMPTY = np.empty(0)


class RangeSource(Protocol):
    """A range sensor the monitor may cast at will (the LiDAR, the low scanner)."""

    name: str

    def cast(self, max_range_m: float) -> LidarScan:
        """A fresh scan from the robot's present pose, rays cut at `max_range_m` [m]."""
        ...

    def reset(self) -> None:
        """Restart for a new episode (noise streams)."""
        ...


@dataclass(frozen=True)
class MonitorConfig:
    """The monitor's zone and timing."""

    margin_m: float = 0.02  # [m] clearance kept beyond the footprint
    scan_period_s: float = 0.1  # [s] sources are re-cast this often (10 Hz sensors)
    reach_m: float = 1.0  # [m] returns farther than this from the centre cannot matter within a stop (0.5 m of sweep)
    brake_fraction: float = 0.8  # share of the acceleration limits the monitor plans its stops with


@dataclass(frozen=True)
class MonitorStop:
    """Why the monitor holds the robot: what it saw, and where."""

    source: str  # the source whose return blocks the motion
    distance_m: float  # [m] from the footprint's edge to the nearest blocking return, now
    points: tuple[tuple[float, float], ...]  # [m] blocking returns in the robot's present frame (x ahead, y left)

    @property
    def reason(self) -> str:
        """One sentence for the run log and the planner."""
        return (
            f"collision monitor stop: an obstacle seen by the {self.source} is {self.distance_m:.2f} m from the "
            f"robot, inside its stopping zone"
        )


@dataclass
class _Cache:
    """One source's latest returns, in the odometry frame."""

    taken_at: float = -math.inf  # [s] sim time
    x: np.ndarray = field(default_factory=lambda: np.empty(0))  # [m]
    y: np.ndarray = field(default_factory=lambda: np.empty(0))  # [m]


class CollisionMonitor:
    """Judges each command (see the module docstring); `admit` is called once per control step."""

    def __init__(
        self,
        spec: RobotSpec,
        sources: Sequence[RangeSource],
        odom: Callable[[], Pose2D],
        clock: Callable[[], float],
        *,
        dt: float,
        max_linear_acc: float,
        max_angular_acc: float,
        config: MonitorConfig | None = None,
    ) -> None:
        """`odom()` is the odometry pose, `clock()` sim time [s], `dt` [s] the control period."""
        if not sources:
            raise ValueError("the collision monitor needs at least one range source")
        self.config = config or MonitorConfig()
        self.spec = spec
        self._sources = list(sources)
        self._odom = odom
        self._clock = clock
        self._dt = dt
        self._acc = self.config.brake_fraction * max_linear_acc  # [m/s^2]
        self._alpha = self.config.brake_fraction * max_angular_acc  # [rad/s^2]
        self._caches = [_Cache() for _ in self._sources]
        self._all: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # every cache's returns, joined
        self._nearest = (0.0, 0.0, 0.0)  # (x [m], y [m]) of the robot at the latest refresh, nearest return [m]
        self.interventions = 0  # control steps on which the command was scaled down or stopped
        self.last_stop: MonitorStop | None = None

    def reset(self) -> None:
        """Forget every cached scan and restart the sources (a new episode)."""
        for source in self._sources:
            source.reset()
        self._caches = [_Cache() for _ in self._sources]
        self._all = None
        self.interventions = 0
        self.last_stop = None

    # --- the check ----------------------------------------------------------------------------------
    def admit(self, v: float, w: float) -> tuple[float, float, MonitorStop | None]:
        """The command (v [m/s], w [rad/s]) the robot may apply now, and a stop when it must halt."""
        if v == 0.0 and w == 0.0:
            return v, w, None
        # Only returns the footprint could reach before stopping can matter (most steps have none).
        reach = self.spec.radius_m + self.config.margin_m + abs(v) * self._horizon(v, w) + 1e-3  # [m]
        px, py, which = self._points(reach)
        if px.size == 0:
            return v, w, None
        fraction, blocking = self._free_fraction(v, w, px, py)
        if fraction >= 1.0:
            return v, w, None
        self.interventions += 1
        if fraction > CREEP_FRACTION:
            return v * fraction, w * fraction, None
        # Stopped. A turn that sweeps nothing closer (always, for a round base) stays allowed.
        keep_w = w if w != 0.0 and v != 0.0 and self._free_fraction(0.0, w, px, py)[0] >= 1.0 else 0.0
        self.last_stop = self._stop(px, py, which, blocking)
        return 0.0, keep_w, self.last_stop

    def _free_fraction(self, v: float, w: float, px: np.ndarray, py: np.ndarray) -> tuple[float, np.ndarray]:
        """The largest share of (v, w) that can still stop clear of every return, and the returns that limit it.

        The footprint is swept along the constant-curvature arc of (v, w) for the arc time
        T = dt + m/2 (one control step, then braking: uniform deceleration covers half the distance the
        same speed would in the braking time m = max(|v|/a, |w|/alpha)). At a share s of the command the arc
        time is s*dt + s^2*m/2; the share is chosen so that it ends before the first pose that touches.
        """
        dt, margin = self._dt, self.config.margin_m
        m = self._braking_time(v, w)
        horizon = dt + m / 2.0  # [s] of arc time at the full command
        n = max(2, int(math.ceil(max(abs(v) * horizon / SAMPLE_STEP_M, abs(w) * horizon / SAMPLE_STEP_RAD))) + 1)
        t = np.arange(n) * (horizon / (n - 1))
        theta = w * t
        if abs(w) < 1e-9:
            cx, cy = v * t, np.zeros(n)
        else:
            radius = v / w
            cx, cy = radius * np.sin(theta), radius * (1.0 - np.cos(theta))
        clearance = self._clearance(cx, cy, theta, px, py)  # [n, points]
        touching = clearance < margin
        touching &= clearance < clearance[0][None, :] - CLOSING_EPS_M  # closing in only
        rows = touching.any(axis=1)
        if not rows.any():
            return 1.0, np.zeros(px.size, dtype=bool)
        first = int(np.argmax(rows))
        free_time = t[first - 1] if first > 0 else 0.0  # [s] of arc time before the first touching pose
        if m <= 1e-12:
            share = free_time / dt
        else:
            share = (-dt + math.sqrt(dt * dt + 2.0 * m * free_time)) / m
        return min(1.0, max(0.0, share)), touching[first]

    def _braking_time(self, v: float, w: float) -> float:
        """[s] to brake from (v, w) to rest at the monitor's share of the acceleration limits."""
        return max(abs(v) / self._acc, abs(w) / self._alpha)

    def _horizon(self, v: float, w: float) -> float:
        """[s] of motion at (v, w) that covers one control step and the braking distance after it."""
        return self._dt + self._braking_time(v, w) / 2.0

    def _clearance(
        self, cx: np.ndarray, cy: np.ndarray, theta: np.ndarray, px: np.ndarray, py: np.ndarray
    ) -> np.ndarray:
        """[m] distance from the footprint at each swept pose to each return (negative inside it)."""
        dx = px[None, :] - cx[:, None]
        dy = py[None, :] - cy[:, None]
        box = self.spec.box_m
        if box is None:
            return np.hypot(dx, dy) - self.spec.radius_m
        c, s = np.cos(theta)[:, None], np.sin(theta)[:, None]
        ex = np.abs(c * dx + s * dy) - box[0] / 2.0
        ey = np.abs(-s * dx + c * dy) - box[1] / 2.0
        outside = np.hypot(np.maximum(ex, 0.0), np.maximum(ey, 0.0))
        return outside + np.minimum(np.maximum(ex, ey), 0.0)

    def _stop(self, px: np.ndarray, py: np.ndarray, which: np.ndarray, blocking: np.ndarray) -> MonitorStop:
        now = self._clearance(np.zeros(1), np.zeros(1), np.zeros(1), px, py)[0]
        index = np.flatnonzero(blocking) if blocking.any() else np.array([int(np.argmin(now))])
        nearest = index[int(np.argmin(now[index]))]
        points = tuple((round(float(px[i]), 3), round(float(py[i]), 3)) for i in index[:64])
        return MonitorStop(self._sources[int(which[nearest])].name, max(0.0, float(now[nearest])), points)

    # --- the sources --------------------------------------------------------------------------------
    def _points(self, reach_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The cached returns within `reach_m` [m] of the robot, in its present frame, with their source's index."""
        now, here = self._clock(), self._odom()
        refreshed = False
        for source, cache in zip(self._sources, self._caches, strict=True):
            if now - cache.taken_at >= self.config.scan_period_s - 1e-9:
                self._refresh(source, cache, here, now)
                refreshed = True
        if refreshed or self._all is None:
            self._all = (
                np.concatenate([c.x for c in self._caches]),
                np.concatenate([c.y for c in self._caches]),
                np.concatenate([np.full(c.x.size, i) for i, c in enumerate(self._caches)]),
            )
            x, y = self._all[0] - here.x, self._all[1] - here.y
            self._nearest = (here.x, here.y, float(np.sqrt((x * x + y * y).min())) if x.size else math.inf)
        # Nothing can have come within reach since the nearest return was measured (the robot has moved
        # less than the gap): no per-return arithmetic on this step.
        ox, oy, nearest = self._nearest
        if nearest - math.hypot(here.x - ox, here.y - oy) > reach_m:
            return _EMPTY, _EMPTY, _EMPTY
        x, y, tags = self._all
        wx, wy = x - here.x, y - here.y
        near = wx * wx + wy * wy <= reach_m * reach_m
        if not near.any():
            return _EMPTY, _EMPTY, _EMPTY
        wx, wy = wx[near], wy[near]
        c, s = math.cos(here.yaw), math.sin(here.yaw)
        return c * wx + s * wy, -s * wx + c * wy, tags[near]

    def _refresh(self, source: RangeSource, cache: _Cache, here: Pose2D, now: float) -> None:
        try:
            scan = source.cast(self.config.reach_m)
            ranges, angles = np.asarray(scan.ranges, dtype=float), np.asarray(scan.angles, dtype=float)
        except Exception as err:  # noqa: BLE001 - any failure of a sensor is the same outage
            raise SensorFailure(f"the {source.name} failed ({one_line(err)}); the robot was stopped") from err
        # inf is "nothing within range"; NaN, or no rays at all, is a sensor that gave nothing to judge by.
        if ranges.size == 0 or ranges.shape != angles.shape or np.isnan(ranges).any():
            raise SensorFailure(f"the {source.name} returned no usable scan; the robot was stopped")
        hit = np.isfinite(ranges) & np.isfinite(angles)
        hit &= ranges <= self.config.reach_m
        r, a = ranges[hit], angles[hit] + here.yaw
        cache.x, cache.y = here.x + r * np.cos(a), here.y + r * np.sin(a)
        cache.taken_at = now
