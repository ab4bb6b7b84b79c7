"""Closed-loop motions of the robot: discrete moves, turns, a point P-controller, velocity ticks.

- `drive` / `rotate` (stepwise source): closed loop on odometry, trapezoid-like speed profile (speed
  limited by the spec and by a braking curve v = sqrt(2 a d) near the goal), heading hold while driving.
- `go_to` (waypoint source): v = k_lin * d capped at v_max, w = k_ang * alpha capped at w_max, rotate in
  place while |alpha| > ang_tol, done within tol_m; optional LiDAR obstacle stop (critical distance in
  +-15 deg ahead) and emergency stop, read every 0.1 s of sim time to stay cheap.
- `velocity_tick` (FSM source): hold (v, w) for dt of sim time; fractional physics steps are carried
  over so sim time stays exact over any number of ticks.

Every motion checks contacts after each physics step: touching a wall or obstacle while moving into it
stops the robot at once, reports `collided`/`collision_with` and counts in `collisions`.
Control runs every physics step (240 Hz); it is a few microseconds of Python beside the physics.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

from llmnav.core.geometry import Pose2D, wrap_angle

if TYPE_CHECKING:
    from llmnav.sim.robot import Robot
    from llmnav.sim.sensors import Lidar, LidarScan


class MotionWorld(Protocol):
    """What motions need of a world (`llmnav.sim.world.World`), so this module does not import it back."""

    robot: Robot
    lidar: Lidar
    body_names: dict[int, str]
    dt: float  # [s] one physics step

    @property
    def sim_time(self) -> float:
        """Simulated time since the world started [s]."""
        ...

    def step(self, n: int = 1) -> None:
        """Advance the physics by n steps."""
        ...


class CommandMonitor(Protocol):
    """What judges every command before the wheels get it (`llmnav.nav.monitor.CollisionMonitor`)."""

    def admit(self, v: float, w: float) -> tuple[float, float, Any]:
        """(v [m/s], w [rad/s]) allowed now, and a stop (with `reason` and `points`) when the robot must halt."""
        ...

    def reset(self) -> None:
        """Forget what was sensed (the episode restarts)."""
        ...


PoseCallback = Callable[[Pose2D, float], None]  # (ground-truth pose, sim time [s])
SampleCallback = Callable[[Pose2D, "LidarScan"], None]  # (ground-truth pose, scan) at each LiDAR check

DRIVE_TOL = 0.002  # [m] drive() goal tolerance on odometry
ROTATE_TOL = 0.002  # [rad] rotate() goal tolerance on odometry
MIN_LINEAR = 0.03  # [m/s] creeping speed so the last millimetres do not take forever
MIN_ANGULAR = 0.05  # [rad/s]
HEADING_GAIN = 4.0  # [1/s] heading hold while driving straight
BRAKE_FRACTION = 0.8  # braking curve uses this share of the acceleration limit (keeps it feasible)
K_LIN = 1.0  # [1/s] go_to linear gain
K_ANG = 2.0  # [1/s] go_to angular gain
GO_TO_W_MAX = 2.0  # [rad/s] go_to turn-rate cap (waypoint source), further capped by the spec
OBSTACLE_HALF_ANGLE = math.radians(15.0)  # [rad] obstacle-stop window ahead
EMERGENCY_HALF_ANGLE = math.radians(90.0)  # [rad] emergency-stop window (the half plane ahead)
LIDAR_PERIOD_S = 0.1  # [s] sim time between LiDAR checks in go_to
SAMPLE_DISTANCE = 0.1  # [m] trajectory sample spacing ...
SAMPLE_PERIOD_S = 0.25  # [s] ... or time spacing, whichever comes first


@dataclass
class MotionResult:
    """How one motion ended."""

    ok: bool  # reached the goal within tolerance
    collided: bool
    collision_with: str | None
    start: Pose2D
    end: Pose2D
    distance_m: float  # travelled (ground truth)
    rotated_rad: float  # signed, accumulated (ground truth)
    duration_s: float  # sim time
    # "collision" | "obstacle" | "emergency" | "timeout" | "vetoed" | "monitor" | None
    stopped_reason: str | None
    # why the guarded motion layer refused the motion ("vetoed": the robot did not move) or the collision
    # monitor stopped it on the way ("monitor")
    veto: str | None = None
    veto_hit: tuple[float, float] | None = None  # [m] robot-frame position of the return that blocked it
    # [m] every return that blocked a monitor stop, in the robot's frame where it stopped (x ahead, y left)
    veto_points: tuple[tuple[float, float], ...] = ()


class _Track:
    """Accumulates ground-truth travel and rotation during one motion."""

    def __init__(self, pose: Pose2D, t: float) -> None:
        self.start = pose
        self.t0 = t
        self.last = pose
        self.distance = 0.0  # [m]
        self.rotated = 0.0  # [rad]

    def update(self, pose: Pose2D) -> None:
        self.distance += math.hypot(pose.x - self.last.x, pose.y - self.last.y)
        self.rotated += wrap_angle(pose.yaw - self.last.yaw)
        self.last = pose


class Motion:
    """Runs motions on a world's robot; `collisions` counts contacts since the last world reset."""

    def __init__(self, world: MotionWorld) -> None:
        self._world = world
        self.on_pose: PoseCallback | None = None
        self.collisions = 0
        self._step_debt = 0.0  # [steps] fractional physics steps owed by velocity_tick
        self._blocked = False  # velocity_tick: was the robot pushing into something last tick
        self._sample_pose: Pose2D | None = None
        self._sample_t = 0.0
        # Judges every command on every physics step; the guarded layer installs it for every planner.
        self.monitor: CommandMonitor | None = None

    def _reset(self) -> None:
        if self.monitor is not None:
            self.monitor.reset()
        self.collisions = 0
        self._step_debt = 0.0
        self._blocked = False
        self._sample_pose = None
        self._sample_t = 0.0

    # --- public motions -------------------------------------------------------------------------
    def drive(self, distance_m: float, *, timeout_s: float | None = None) -> MotionResult:
        """Drive straight `distance_m` [m] (+ forward, - backward), closed loop on odometry."""
        robot = self._world.robot
        spec = robot.spec
        o0 = robot.odom()
        ux, uy = math.cos(o0.yaw), math.sin(o0.yaw)
        brake = BRAKE_FRACTION * robot.max_linear_acc  # [m/s^2]
        timeout = timeout_s if timeout_s is not None else abs(distance_m) / spec.max_linear * 2.0 + 5.0

        def control() -> tuple[float, float] | None:
            o = robot.odom()
            remaining = distance_m - ((o.x - o0.x) * ux + (o.y - o0.y) * uy)  # [m] signed, along the line
            if abs(remaining) <= DRIVE_TOL:
                return None
            speed = max(MIN_LINEAR, min(spec.max_linear, math.sqrt(2.0 * brake * abs(remaining))))
            return math.copysign(speed, remaining), HEADING_GAIN * wrap_angle(o0.yaw - o.yaw)

        return self._run(control, timeout)

    def rotate(self, angle_rad: float, *, timeout_s: float | None = None) -> MotionResult:
        """Turn in place by `angle_rad` [rad] (+ CCW = ROTATE_LEFT, - CW), closed loop on odometry."""
        robot = self._world.robot
        spec = robot.spec
        brake = BRAKE_FRACTION * robot.max_angular_acc  # [rad/s^2]
        timeout = timeout_s if timeout_s is not None else abs(angle_rad) / spec.max_angular * 2.0 + 5.0
        turned = 0.0  # [rad] unwrapped odometry rotation so far
        last_yaw = robot.odom().yaw

        def control() -> tuple[float, float] | None:
            nonlocal turned, last_yaw
            yaw = robot.odom().yaw
            turned += wrap_angle(yaw - last_yaw)
            last_yaw = yaw
            remaining = angle_rad - turned  # [rad]
            if abs(remaining) <= ROTATE_TOL:
                return None
            rate = max(MIN_ANGULAR, min(spec.max_angular, math.sqrt(2.0 * brake * abs(remaining))))
            return 0.0, math.copysign(rate, remaining)

        return self._run(control, timeout)

    def go_to(
        self,
        x: float,
        y: float,
        *,
        tol_m: float = 0.1,
        ang_tol: float = 0.087,
        v_max: float | None = None,
        w_max: float | None = None,
        obstacle_stop_m: float | None = None,
        emergency_stop_m: float | None = None,
        on_sample: SampleCallback | None = None,
        timeout_s: float | None = None,
    ) -> MotionResult:
        """P-control to the world point (x, y) on odometry (odometry frame = world frame at reset).

        `on_sample(pose, scan)` sees every LiDAR check (every 0.1 s sim when a stop distance or
        `on_sample` is given). Obstacle and emergency stops apply while driving, not while turning in place.
        """
        robot, world = self._world.robot, self._world
        spec = robot.spec
        v_cap = min(v_max if v_max is not None else spec.max_linear, spec.max_linear)  # [m/s]
        w_cap = min(w_max if w_max is not None else GO_TO_W_MAX, spec.max_angular)  # [rad/s]
        o0 = robot.odom()
        distance = o0.distance_to(x, y)
        if timeout_s is None:  # generous: three straight runs plus two full turns
            timeout_s = distance / v_cap * 3.0 + 4.0 * math.pi / w_cap + 10.0
        use_lidar = obstacle_stop_m is not None or emergency_stop_m is not None or on_sample is not None
        period = max(1, round(LIDAR_PERIOD_S / world.dt))  # [steps]
        steps = 0
        stop_reason: str | None = None

        # Without a sample consumer only the rays the stops read matter, out to the larger stop distance:
        # the half plane ahead, or the obstacle window alone without an emergency stop. Noisy rays draw
        # one noise value each, so a noisy LiDAR still casts the half plane (the same draws as ever).
        reach = max(d for d in (obstacle_stop_m, emergency_stop_m, 0.0) if d is not None) + 0.5  # [m]
        narrow = emergency_stop_m is None and world.lidar.config.noise_std_m == 0.0
        window = OBSTACLE_HALF_ANGLE if narrow else EMERGENCY_HALF_ANGLE  # [rad]

        def check_lidar(driving: bool) -> str | None:
            if on_sample is None and not driving:
                return None
            if on_sample is not None:
                scan = world.lidar.scan()
                on_sample(robot.pose(), scan)
            else:
                scan = world.lidar.scan(half_angle=window, max_range=reach)
            if not driving:
                return None
            if emergency_stop_m is not None:
                ahead = scan.min_in(-EMERGENCY_HALF_ANGLE, EMERGENCY_HALF_ANGLE)  # [m]
                if ahead < emergency_stop_m:
                    return "emergency"
            front = scan.min_in(-OBSTACLE_HALF_ANGLE, OBSTACLE_HALF_ANGLE)  # [m]
            if obstacle_stop_m is not None and front < obstacle_stop_m:
                return "obstacle"
            return None

        def control() -> tuple[float, float] | None:
            nonlocal steps, stop_reason
            o = robot.odom()
            d = o.distance_to(x, y)
            if d <= tol_m:
                return None
            alpha = o.bearing_to(x, y)
            driving = abs(alpha) <= ang_tol
            if use_lidar and steps % period == 0:
                stop_reason = check_lidar(driving)
                if stop_reason is not None:
                    return None
            steps += 1
            w = min(max(K_ANG * alpha, -w_cap), w_cap)
            if not driving:
                return 0.0, w
            return min(v_cap, K_LIN * d), w

        result = self._run(control, timeout_s)
        if stop_reason is not None:
            result.ok = False
            result.stopped_reason = stop_reason
        return result

    def velocity_tick(self, v: float, w: float, dt: float = 0.02) -> MotionResult:
        """Hold (v [m/s], w [rad/s]) for `dt` [s] of sim time (50 Hz by default).

        240 Hz / 50 Hz is 4.8 steps: the fraction is carried to the next tick, so sim time is exact over
        many ticks. A collision halts the robot at once; the rest of the tick passes standing still.
        """
        world, robot = self._world, self._world.robot
        self._step_debt += dt / world.dt
        steps = int(self._step_debt + 1e-9)
        self._step_debt -= steps
        track = _Track(robot.pose(), world.sim_time)
        robot.set_velocity(v, w)
        monitor = self.monitor
        held: Any = None  # the monitor's last stop within this tick
        hit: str | None = None
        for _ in range(steps):
            if monitor is not None:
                robot.set_velocity(v, w)
                av, aw, stop = monitor.admit(*robot.command())
                robot.set_velocity(av, aw)
                held = stop if stop is not None else held
            world.step(1)
            track.update(robot.pose())
            self._maybe_sample(robot.pose(), world.sim_time)
            if hit is None:
                hit = self._blocking_contact()
                if hit is not None:
                    robot.halt()
        if hit is not None and not self._blocked:
            self.collisions += 1
        self._blocked = hit is not None
        result = self._result(track, ok=hit is None, hit=hit, reason="collision" if hit else None)
        if held is not None and hit is None:
            _mark_stop(result, held)
        return result

    # --- machinery ------------------------------------------------------------------------------
    def _run(self, control: Callable[[], tuple[float, float] | None], timeout_s: float) -> MotionResult:
        world, robot = self._world, self._world.robot
        track = _Track(robot.pose(), world.sim_time)
        max_steps = int(math.ceil(timeout_s / world.dt))
        monitor = self.monitor
        hit: str | None = None
        held: Any = None  # the monitor's stop: the motion brakes to rest, then ends
        reached = False
        for _ in range(max_steps):
            command = control() if held is None else (0.0, 0.0)
            if command is None:
                reached = True
                break
            robot.set_velocity(*command)
            if monitor is not None and held is None:
                av, aw, held = monitor.admit(*robot.command())
                robot.set_velocity(*((0.0, 0.0) if held is not None else (av, aw)))
            if held is not None:
                moving_v, moving_w = robot.velocity()
                if moving_v == 0.0 and moving_w == 0.0:
                    break
            world.step(1)
            pose = robot.pose()
            track.update(pose)
            self._maybe_sample(pose, world.sim_time)
            hit = self._blocking_contact()
            if hit is not None:
                break
        robot.halt()
        self._emit_sample(robot.pose(), world.sim_time)
        if hit is not None:
            self.collisions += 1
            return self._result(track, ok=False, hit=hit, reason="collision")
        if held is not None:
            return _mark_stop(self._result(track, ok=False, hit=None, reason="monitor"), held)
        return self._result(track, ok=reached, hit=None, reason=None if reached else "timeout")

    def _blocking_contact(self) -> str | None:
        """Name of a body the robot touches while moving into it (or deeply penetrates), else None."""
        robot = self._world.robot
        points = robot.contact_points_at()
        if not points:
            return None
        v, w = robot.velocity()
        pose = robot.pose()
        vx, vy = v * math.cos(pose.yaw), v * math.sin(pose.yaw)
        for body, nx, ny, dist, px, py in points:
            # The contact point's own velocity: the base's, plus the turn's (a box's corner sweeps while turning).
            cvx, cvy = vx - w * (py - pose.y), vy + w * (px - pose.x)
            if cvx * nx + cvy * ny < -1e-4 or dist < -0.005:  # the normal points from the obstacle to the robot
                return self._world.body_names.get(body, f"body:{body}")
        return None

    def _result(self, track: _Track, *, ok: bool, hit: str | None, reason: str | None) -> MotionResult:
        world = self._world
        return MotionResult(
            ok=ok,
            collided=hit is not None,
            collision_with=hit,
            start=track.start,
            end=world.robot.pose(),
            distance_m=track.distance,
            rotated_rad=track.rotated,
            duration_s=world.sim_time - track.t0,
            stopped_reason=reason,
        )

    def _maybe_sample(self, pose: Pose2D, t: float) -> None:
        if self.on_pose is None:
            return
        last = self._sample_pose
        if (
            last is None
            or t - self._sample_t >= SAMPLE_PERIOD_S
            or math.hypot(pose.x - last.x, pose.y - last.y) >= SAMPLE_DISTANCE
        ):
            self._emit_sample(pose, t)

    def _emit_sample(self, pose: Pose2D, t: float) -> None:
        if self.on_pose is None:
            return
        self._sample_pose = pose
        self._sample_t = t
        self.on_pose(pose, t)


def _mark_stop(result: MotionResult, stop: Any) -> MotionResult:
    """`result` carrying the monitor's stop: its reason, nearest blocking return and all of them."""
    points = tuple(stop.points)
    result.stopped_reason = "monitor"
    result.veto = stop.reason
    result.veto_hit = min(points, key=lambda p: math.hypot(*p)) if points else None
    result.veto_points = points
    return result
