"""The guarded motion layer: every motion a planner commands is checked here before the robot moves.

Planners never hold the simulator's `Motion`; they get a `GuardedMotion` (through `PlannerWorld.motion`),
so no planner can step around these checks, whoever asks:

- `drive(d)` (stepwise FRONT/BACK): the swept-corridor veto (`check_motion`, box footprint) on the
  latest LiDAR scan. Blocked: the robot does not move, the result says `stopped_reason="vetoed"` with
  the reason in `veto`, and a `guard` event with outcome `veto` is logged.
- `go_to(x, y)` (waypoint segments, hybrid legs, the baselines' legs): the same veto on the straight leg
  from the robot to (x, y), turned toward the leg, with the round base's own swept disc and small margins
  (legs are planned on grids already clear of known walls); a leg through something the map lacks is
  vetoed before the robot starts it. Its LiDAR stops keep watching while the leg runs. A planner that
  checks a leg first (`check_leg`, as `llmnav.guard.legs.drive_leg` does) records a refusal with
  `refuse_leg`, so it is counted and logged the same way.
- `velocity_tick(v, w)` (the FSM and any continuous planner): the command is first clipped onto the
  robot's kinematic box (`VelocityLimits`), then its time to collision is checked: the round base moving
  on the commanded arc must be able to travel one tick plus its braking distance plus a stop margin
  without touching any LiDAR return (scans are taken at most every `scan_period_s`, the travel since
  the scan counts against the margin). A command that fails keeps its turn rate and loses its forward
  speed (turning in place sweeps nothing new). Commanded and applied commands are both logged (an
  `override` event) whenever they differ, and the first tick of each override is a `guard` veto.
- `rotate` and standing still are not checked: a round base sweeps no new area turning in place.

Vetoes judge sensor data only, never model text. What the planner made of a veto (ask the model again,
replan, give up) is the planner's business; the layer only guarantees the robot did not make that move.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from llmnav.core.geometry import Pose2D
from llmnav.guard.schemas import VelocityLimits
from llmnav.guard.veto import VetoResult, check_motion
from llmnav.sim.motion import MotionResult
from llmnav.sim.sensors import LidarScan

if TYPE_CHECKING:
    from llmnav.core.robot_specs import RobotSpec
    from llmnav.nav.monitor import CollisionMonitor
    from llmnav.sim.motion import Motion


BACK_OFF_M = 0.15  # [m] reverse after a monitor stop, so a new plan starts clear of what stopped the robot


class EventSink(Protocol):
    """Where the layer logs its vetoes and overrides (the run log)."""

    def event(self, kind: str, **fields: Any) -> None:
        """Log one event."""
        ...


class ScanSource(Protocol):
    """The LiDAR as the layer sees it: the latest full scan, fresh when the robot has moved since."""

    def latest(self, max_age_s: float) -> tuple[LidarScan, Pose2D]:
        """(a full scan no older than `max_age_s` [s] of sim time, the robot's pose when it was taken)."""
        ...


class PoseSource(Protocol):
    """Ground-truth pose, odometry, sim time and the robot's numbers."""

    spec: RobotSpec

    def pose(self) -> Any:
        """Ground-truth pose."""
        ...

    def odom(self) -> Any:
        """Odometry pose (the frame go_to steers in)."""
        ...


@dataclass(frozen=True)
class MotionGuardConfig:
    """Margins of the layer's checks."""

    drive_margin_m: float = 0.15  # [m] lateral margin of a FRONT/BACK's swept box (check_motion's default)
    drive_stop_margin_m: float = 0.2  # [m] ... and its stop margin
    leg_margin_m: float = 0.02  # [m] radius added to the round base on a go_to leg
    leg_stop_margin_m: float = 0.02  # [m] stop margin at the end of a go_to leg
    tick_margin_m: float = 0.02  # [m] clearance a velocity command must keep beyond the robot's radius
    scan_period_s: float = 0.1  # [s] velocity ticks reuse a scan this long (a 10 Hz LiDAR)
    leg_min_m: float = 0.02  # [m] shorter legs are turns in place: nothing to sweep


class GuardedMotion:
    """The motion interface planners get. See the module docstring."""

    def __init__(
        self,
        motion: Motion,
        robot: PoseSource,
        scans: ScanSource,
        log: EventSink,
        *,
        robot_max_linear_acc: float,
        config: MotionGuardConfig | None = None,
        low_scans: ScanSource | None = None,
        monitor: CollisionMonitor | None = None,
    ) -> None:
        """`low_scans` (the low scanner) joins every check; `monitor` is the one installed in `motion`."""
        self.__motion = motion
        self.__robot = robot
        self.__scans = _Merged(scans, low_scans) if low_scans is not None else scans
        self.__low = low_scans
        self.__monitor = monitor
        self.__log = log
        self.__brake = robot_max_linear_acc  # [m/s^2]
        self.__cfg = config or MotionGuardConfig()
        spec = robot.spec
        self.__box = VelocityLimits(spec.max_linear, spec.max_angular)
        self.__overriding = False
        self.__held = False  # was the last velocity tick stopped by the monitor
        self.vetoes = 0  # motions this layer refused (velocity overrides count once per run of ticks)

    # --- checks (no motion) ---------------------------------------------------------------------
    def check_straight(self, distance_m: float, *, scan: LidarScan | None = None) -> VetoResult:
        """The veto's verdict on a FRONT/BACK of `distance_m` [m] (+ forward), without moving.

        `scan` defaults to the latest scan at the current pose (the one an observation just took).
        """
        spec = self.__robot.spec
        if scan is None:
            scan = self.__scans.latest(0.0)[0]
        elif self.__low is not None:
            scan = merge_scans(scan, self.__low.latest(0.0)[0])
        return check_motion(
            distance_m,
            scan,
            robot_width_m=spec.width_m,
            robot_radius_m=spec.radius_m,
            margin_m=self.__cfg.drive_margin_m,
            stop_margin_m=self.__cfg.drive_stop_margin_m,
        )

    def check_leg(self, x: float, y: float) -> VetoResult:
        """The veto's verdict on a straight leg from the robot to the point (x, y) [m] of go_to's frame.

        go_to steers on odometry, so the leg the robot will drive is the one from its odometry pose to
        (x, y): that is the one judged (against the scan, which is in the robot's own frame).
        """
        pose = self.__robot.odom()
        length = math.hypot(x - pose.x, y - pose.y)
        if length < self.__cfg.leg_min_m:
            return VetoResult(True, math.inf, None)
        spec = self.__robot.spec
        return check_motion(
            length,
            self.__scans.latest(0.0)[0],
            robot_width_m=spec.width_m,
            robot_radius_m=spec.radius_m,
            margin_m=self.__cfg.leg_margin_m,
            stop_margin_m=self.__cfg.leg_stop_margin_m,
            direction_rad=pose.bearing_to(x, y),
            footprint="disc",
        )

    # --- motions ----------------------------------------------------------------------------------
    def drive(self, distance_m: float, *, timeout_s: float | None = None) -> MotionResult:
        """Drive straight `distance_m` [m] (+ forward, - backward) unless the veto blocks it."""
        verdict = self.check_straight(distance_m)
        command = "FRONT" if distance_m >= 0 else "BACK"
        if not verdict.allowed:
            return self.__refuse(command, distance_m, verdict)
        return self.__watched(command, distance_m, self.__motion.drive(distance_m, timeout_s=timeout_s))

    def rotate(self, angle_rad: float, *, timeout_s: float | None = None) -> MotionResult:
        """Turn in place by `angle_rad` [rad] (+ CCW), watched by the monitor (a box base's corners sweep)."""
        command = "ROTATE_LEFT" if angle_rad >= 0 else "ROTATE_RIGHT"
        return self.__watched(command, round(angle_rad, 4), self.__motion.rotate(angle_rad, timeout_s=timeout_s))

    def go_to(self, x: float, y: float, **options: Any) -> MotionResult:
        """P-control to (x, y) [m] (see `Motion.go_to` for the options) unless the leg is vetoed."""
        verdict = self.check_leg(x, y)
        if not verdict.allowed:
            return self.refuse_leg(x, y, verdict)
        return self.__watched("GO_TO", [round(x, 3), round(y, 3)], self.__motion.go_to(x, y, **options))

    def refuse_leg(self, x: float, y: float, verdict: VetoResult, *, step: int | None = None) -> MotionResult:
        """Record a leg to (x, y) [m] that `check_leg` refused, without moving; its vetoed result.

        For a planner that checked the leg first: the refusal is counted and logged (naming the planner's
        `step`) exactly as `go_to` would have done it.
        """
        return self.__refuse("GO_TO", [round(x, 3), round(y, 3)], verdict, step=step)

    def velocity_tick(self, v: float, w: float, dt: float = 0.02) -> MotionResult:
        """Hold (v [m/s], w [rad/s]) for `dt` [s] after the kinematic box and the time-to-collision check."""
        applied_v, applied_w, reason = self.__admissible(v, w, dt)
        differs = (applied_v, applied_w) != (v, w)
        if differs:
            commanded = [_num(v), _num(w)]
            self.__log.event("override", commanded=commanded, applied=[applied_v, applied_w], reason=reason)
            if not self.__overriding:
                self.vetoes += 1
                self.__log.event("guard", step=None, attempt=1, outcome="veto", error=reason, motion="velocity")
        self.__overriding = differs
        result = self.__motion.velocity_tick(applied_v, applied_w, dt)
        if result.stopped_reason == "monitor" and not self.__held:
            self.__watched("velocity", [_num(applied_v), _num(applied_w)], result)
        self.__held = result.stopped_reason == "monitor"
        return result

    def back_off(self, distance_m: float = BACK_OFF_M) -> MotionResult:
        """Recovery after a stop: reverse `distance_m` [m] if nothing is behind (nav2's BackUp behaviour).

        The reverse goes through the same veto and monitor as any motion; a `recovery` event records it.
        """
        result = self.drive(-abs(distance_m))
        self.__log.event(
            "recovery",
            behaviour="back_off",
            distance_m=round(abs(distance_m), 3),
            travelled_m=round(result.distance_m, 4),
            outcome="done" if result.ok else (result.stopped_reason or "failed"),
        )
        return result

    @property
    def collisions(self) -> int:
        """Contacts since the episode started."""
        return self.__motion.collisions

    # --- machinery ------------------------------------------------------------------------------
    def __watched(self, command: str, parameters: Any, result: MotionResult) -> MotionResult:
        """A motion's result; a collision-monitor stop on the way is counted and logged as a veto."""
        if result.stopped_reason != "monitor":
            return result
        self.vetoes += 1
        stop = self.__monitor.last_stop if self.__monitor is not None else None
        self.__log.event(
            "guard",
            step=None,
            attempt=1,
            outcome="veto",
            error=result.veto,
            motion=command,
            parameters=parameters,
            source=stop.source if stop is not None else None,
            zone="stop",
            distance_m=round(stop.distance_m, 3) if stop is not None else None,
        )
        return result

    def __refuse(self, command: str, parameters: Any, verdict: VetoResult, *, step: int | None = None) -> MotionResult:
        self.vetoes += 1
        self.__log.event(
            "guard", step=step, attempt=1, outcome="veto", error=verdict.reason, motion=command, parameters=parameters
        )
        here = self.__robot.pose()
        return MotionResult(
            ok=False,
            collided=False,
            collision_with=None,
            start=here,
            end=here,
            distance_m=0.0,
            rotated_rad=0.0,
            duration_s=0.0,
            stopped_reason="vetoed",
            veto=verdict.reason,
            veto_hit=verdict.hit,
        )

    def __admissible(self, v: float, w: float, dt: float) -> tuple[float, float, str | None]:
        """The command actually applied and why it differs (None when it does not)."""
        if not (isinstance(v, int | float) and isinstance(w, int | float) and math.isfinite(v) and math.isfinite(w)):
            return 0.0, 0.0, f"command ({v!r}, {w!r}) is not a pair of finite numbers: stopped"
        box_v, box_w = self.__box.project(float(v), float(w))
        reason = self.__box.violation(float(v), float(w))
        if box_v == 0.0:
            return box_v, box_w, reason
        blocked = self.__ttc_blocked(box_v, box_w, dt)
        if blocked is not None:
            return 0.0, box_w, blocked
        return box_v, box_w, reason

    def __ttc_blocked(self, v: float, w: float, dt: float) -> str | None:
        """Why (v, w) would run the robot into a LiDAR return before it could stop, or None."""
        cfg = self.__cfg
        scan, seen_from = self.__scans.latest(cfg.scan_period_s)
        spec = self.__robot.spec
        need = abs(v) * dt + v * v / (2.0 * self.__brake) + cfg.tick_margin_m  # [m] of path to keep clear
        reach = spec.radius_m + cfg.tick_margin_m  # [m] disc that must stay clear of every return
        hits = np.isfinite(scan.ranges) & np.isfinite(scan.angles)
        if scan.angles.size == 0:
            return "no LiDAR scan to check the command against: forward speed set to 0"
        # Returns in the robot's present frame (it may have moved since the scan).
        here = self.__robot.pose()
        r, a = scan.ranges[hits], scan.angles[hits] + seen_from.yaw
        wx, wy = seen_from.x + r * np.cos(a) - here.x, seen_from.y + r * np.sin(a) - here.y
        c, s_ = math.cos(here.yaw), math.sin(here.yaw)
        px_all, py_all = c * wx + s_ * wy, -s_ * wx + c * wy
        near = np.hypot(px_all, py_all) <= need + reach + 1e-9
        if not near.any():
            return None
        px, py = px_all[near], py_all[near]
        # Sample the arc every 1 cm of path (and its end) in the robot's frame at the scan.
        n = max(2, int(math.ceil(need / 0.01)) + 1)
        s = np.linspace(0.0, need, n) * (1.0 if v >= 0 else -1.0)
        if abs(w) < 1e-9:
            cx, cy = s, np.zeros_like(s)
        else:
            radius = v / w
            theta = s / radius
            cx, cy = radius * np.sin(theta), radius * (1.0 - np.cos(theta))
        d2 = (cx[:, None] - px[None, :]) ** 2 + (cy[:, None] - py[None, :]) ** 2
        # A return the robot already overlaps but moves away from is no reason to stop it.
        start = d2[0]
        closing = d2 < reach**2
        closing &= d2 < start[None, :] - 1e-12
        if closing.any():
            first = int(np.argmax(closing.any(axis=1)))
            ahead = abs(float(s[first]))
            return (
                f"command ({v:.3g} m/s, {w:.3g} rad/s) would bring the robot within {cfg.tick_margin_m:g} m of an "
                f"obstacle after {ahead:.2f} m, inside its stopping distance: forward speed set to 0"
            )
        return None


def _num(value: Any) -> Any:
    return (
        round(value, 4)
        if isinstance(value, float) and math.isfinite(value)
        else value
        if isinstance(value, int)
        else str(value)
    )


def merge_scans(first: LidarScan, second: LidarScan) -> LidarScan:
    """Both scanners' rays as one scan (both measure from the robot's centre): every check sees either's returns."""
    return LidarScan(
        angles=np.concatenate((first.angles, second.angles)),
        ranges=np.concatenate((first.ranges, second.ranges)),
        range_max=max(first.range_max, second.range_max),
        range_min=min(first.range_min, second.range_min),
    )


class _Merged:
    """Two scan sources read as one (the LiDAR and the low scanner)."""

    def __init__(self, first: ScanSource, second: ScanSource) -> None:
        self.__first = first
        self.__second = second

    def latest(self, max_age_s: float) -> tuple[LidarScan, Pose2D]:
        """Both latest scans merged, with the pose the first was taken from."""
        scan, pose = self.__first.latest(max_age_s)
        low, low_pose = self.__second.latest(max_age_s)
        return merge_scans(scan, _seen_from(low, low_pose, pose)), pose


def _seen_from(scan: LidarScan, taken_at: Pose2D, here: Pose2D) -> LidarScan:
    """`scan`, taken at `taken_at`, as polar returns from `here` (rays without a return keep their direction)."""
    if (taken_at.x, taken_at.y, taken_at.yaw) == (here.x, here.y, here.yaw):
        return scan
    a = scan.angles + taken_at.yaw
    finite = np.isfinite(scan.ranges)
    r = np.where(finite, scan.ranges, 0.0)
    wx, wy = taken_at.x + r * np.cos(a) - here.x, taken_at.y + r * np.sin(a) - here.y
    angles = np.where(finite, np.arctan2(wy, wx) - here.yaw, a - here.yaw)
    angles = (angles + np.pi) % (2.0 * np.pi) - np.pi
    ranges = np.where(finite, np.hypot(wx, wy), np.inf)
    return LidarScan(angles=angles, ranges=ranges, range_max=scan.range_max, range_min=scan.range_min)
