"""Driving a planned path in the simulator, shared by the oracle and frontier baselines.

Each helper commands the guarded motion layer (`ctx.world.motion`; legs through `llmnav.guard.legs`),
logs one `action` event per motion and keeps a running `Drive` tally. A leg the layer vetoes ends the
drive like any failed motion; `drive_planned` then recovers: it marks what blocked the leg and plans again.
Where the robot is comes from a `Belief`: the true pose with `oracle` information, odometry corrected by
scan matching with `sensed` (the map and the targets stay the baselines' own: they are yardsticks).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

from llmnav.core.geometry import Point, Pose2D
from llmnav.guard.legs import Action, drive_leg
from llmnav.mapping.grid import GridGeometry, LidarMap, margins_from
from llmnav.mapping.targets import OracleConfig, OraclePath, plan_to_targets, scenario_grid, with_added_obstacles
from llmnav.nav.localize import Localizer
from llmnav.planners.base import EpisodeContext, EpisodeOutcome, StepInfo

if TYPE_CHECKING:
    from llmnav.sim.motion import MotionResult
    from llmnav.world.scenario import Scenario, Target

REPLANS_AFTER_REFUSAL = 4  # plans after legs the motion layer refused, per drive to a target
REFUSAL_MARK_M = 0.05  # [m] side of the box marked where a refused leg's blocking return was
MAP_RESOLUTION_M = 0.05  # [m] cells of the LiDAR map a baseline builds (the localizer's map)
# [m] Sensed, the far edge of the approach band is pulled in by what the believed pose may be off at the end
# (the localizer is held to 0.10 m median, 0.30 m max): a stop planned 0.1 m inside the success radius
# ended 2.51 m from a target when the belief was 0.08 m off.
POSE_SLACK_M = 0.2


class Belief:
    """Where a baseline believes the robot is, and the LiDAR map it builds on the way.

    `oracle` information: the true pose. `sensed`: odometry corrected by the scan-to-map localizer
    (`llmnav.nav.localize`, as in the hybrid planner): each scan is registered against the map the earlier
    scans built, then integrated at the corrected pose, and the estimate is logged as a `localize` event
    (the summary's `pose_error_m` scores it against the truth). `mapping`: keep the map even when the
    pose is true (frontier exploration plans on it); the oracle with `oracle` information keeps none and
    takes no scans.
    """

    def __init__(self, ctx: EpisodeContext, *, mapping: bool = False, resolution_m: float = MAP_RESOLUTION_M) -> None:
        self.ctx = ctx
        sensed = ctx.information == "sensed"
        self.localizer = Localizer() if sensed else None
        geometry = GridGeometry.from_bounds(ctx.scenario.bounds, resolution_m)
        self.map = LidarMap(geometry) if mapping or sensed else None

    def pose(self) -> Pose2D:
        """The pose the baseline acts on [m, rad]."""
        robot = self.ctx.world.robot
        return robot.pose() if self.localizer is None else self.localizer.pose(robot.odom())

    def sense(self) -> Pose2D:
        """One scan: localize on it (sensed), then add it and the low scanner's returns to the map."""
        if self.map is None:
            return self.pose()
        world = self.ctx.world
        scan = world.lidar.scan()
        if self.localizer is not None:
            match = self.localizer.update(world.robot.odom(), scan, self.map)
            self.ctx.event("localize", pose=match.pose.as_list(), **match.fields())
        pose = self.pose()
        self.map.integrate(pose, scan)
        self.map.mark_hits(pose, world.low_lidar.scan())
        return pose

    def in_odometry_frame(self, x: float, y: float) -> tuple[float, float]:
        """A point [m] of the map frame in the odometry frame `go_to` steers in, as the belief stands now.

        Drift gathered on earlier legs is taken out instead of adding up (uncorrected, 0.6 m after a 12 m
        drive stopped the oracle outside the 2.5 m success radius).
        """
        return self.pose().carry(x, y, self.ctx.world.robot.odom())


@dataclass
class Drive:
    """What a sequence of motions did."""

    travelled_m: float = 0.0  # [m] ground-truth distance driven
    steps: int = 0  # motions executed (action events logged)
    last: MotionResult | None = None

    @property
    def ok(self) -> bool:
        """Whether the last motion reached its goal."""
        return self.last is None or self.last.ok


def log_action(ctx: EpisodeContext, step: int, command: str, parameters: object, result: MotionResult) -> None:
    """One `action` event for a motion (and a line in the live view)."""
    ctx.log.sim_time = ctx.world.sim_time
    Action.of(step, command, parameters, result).log(ctx.log)
    ctx.view.on_step(StepInfo(step=step, action=f"{command} {parameters}"))


def drive_waypoints(
    ctx: EpisodeContext,
    waypoints: Sequence[Point],
    drive: Drive,
    belief: Belief,
    *,
    tol_m: float = 0.1,
    final_tol_m: float = 0.05,
    obstacle_stop_m: float | None = None,
) -> Drive:
    """go_to each waypoint in turn, logging one `action` per waypoint; stops at the first failed motion.

    go_to steers on odometry: each leg's goal is carried into the odometry frame from the believed pose
    (`Belief.in_odometry_frame`); sensed, a scan corrects that belief before every leg.
    """
    for i, (x, y) in enumerate(waypoints):
        tol = final_tol_m if i == len(waypoints) - 1 else tol_m
        if belief.localizer is not None:
            belief.sense()
        gx, gy = belief.in_odometry_frame(x, y)
        drive.steps += 1
        parameters = [round(x, 3), round(y, 3)]
        result = drive_leg(
            ctx.world,
            gx,
            gy,
            step=drive.steps,
            log=ctx.log,
            parameters=parameters,
            tol_m=tol,
            obstacle_stop_m=obstacle_stop_m,
        )
        drive.travelled_m += result.distance_m
        drive.last = result
        ctx.view.on_step(StepInfo(step=drive.steps, action=f"GO_TO {parameters}"))
        if not result.ok:
            break
    return drive


def plan_to(scenario: Scenario, targets: Sequence[Target], start: Point, config: OracleConfig) -> OraclePath | None:
    """The shortest path to the targets on the true map with `config`'s clearance, else through narrower passages.

    A doorway of the robot's width + 0.3 m leaves no room at the full margin; with less, the leg check and
    the collision monitor still keep the robot off the frame.
    """
    for margin in margins_from(config.grid.margin_m):
        narrow = replace(config, grid=replace(config.grid, margin_m=margin))
        path = plan_to_targets(scenario_grid(scenario, narrow.grid), scenario, targets, start, narrow)
        if path is not None:
            return path
    return None


def drive_planned(
    ctx: EpisodeContext,
    scenario: Scenario,
    targets: Sequence[Target],
    config: OracleConfig,
    drive: Drive,
    belief: Belief,
    *,
    on_path: Callable[[OraclePath, int], None],
    replans: int = REPLANS_AFTER_REFUSAL,
) -> OraclePath | None:
    """Plan on the true map from the believed pose and drive it; recover from refused legs. None: no path.

    A leg the motion layer refuses, or the collision monitor stops (it has backed off already), saw a
    return the map lacks or the plan grazed (a leg starts off its corner, cells are coarse, a doorway is
    tight): the return is marked on the map as a small box and the path is planned again from where the
    robot stands, `replans` times at most. `on_path(path, attempt)` sees every plan before it is driven.
    Sensed, a last scan corrects the belief where the drive ended, and the stop is planned `POSE_SLACK_M`
    farther inside the approach band's far edge.
    """
    if belief.localizer is not None:
        config = replace(config, approach_max_m=config.approach_max_m - POSE_SLACK_M)
    path: OraclePath | None = None
    for attempt in range(1 + replans):
        pose = belief.pose()
        path = plan_to(scenario, targets, (pose.x, pose.y), config)
        if path is None:
            return None
        on_path(path, attempt)
        tolerances = {"tol_m": config.waypoint_tol_m, "final_tol_m": config.final_tol_m}
        drive_waypoints(ctx, path.waypoints, drive, belief, **tolerances)
        if belief.localizer is not None:
            belief.sense()
        last = drive.last
        if drive.ok or last is None or last.veto_hit is None:
            break
        here = belief.pose()
        mark = here.point_at(math.atan2(last.veto_hit[1], last.veto_hit[0]), math.hypot(*last.veto_hit))
        scenario = with_added_obstacles(scenario, [mark], REFUSAL_MARK_M, prefix="refused")
        ctx.log.event("planner", kind="refusal_mark", point=[round(mark[0], 3), round(mark[1], 3)])
    return path


def rotate_by(ctx: EpisodeContext, angle_rad: float, drive: Drive) -> Drive:
    """One logged in-place rotation (positive = counter-clockwise)."""
    result = ctx.world.motion.rotate(angle_rad)
    drive.steps += 1
    drive.travelled_m += result.distance_m
    drive.last = result
    command = "ROTATE_LEFT" if angle_rad >= 0 else "ROTATE_RIGHT"
    log_action(ctx, drive.steps, command, round(math.degrees(abs(angle_rad)), 2), result)
    return drive


def face_point(
    ctx: EpisodeContext, point: Point, drive: Drive, belief: Belief, *, min_angle_rad: float = 0.02
) -> Drive:
    """Turn in place to face a point (skipped when already within `min_angle_rad` [rad])."""
    bearing = belief.pose().bearing_to(*point)
    if abs(bearing) < min_angle_rad:
        return drive
    return rotate_by(ctx, bearing, drive)


def failure_reason(result: MotionResult | None) -> str:
    """One line saying why a motion stopped."""
    if result is None:
        return "no motion"
    if result.collided:
        return f"collision with {result.collision_with or 'an obstacle'}"
    if result.veto is not None:
        return f"motion vetoed: {result.veto}"
    return f"motion stopped: {result.stopped_reason or 'goal not reached'}"


def run_untargeted(ctx: EpisodeContext, drive: Drive) -> EpisodeOutcome:
    """Tasks without targets: `rotate` turns 360° (four quarter turns), `explore` ends at once."""
    if ctx.task.kind != "rotate":
        return EpisodeOutcome("completed", "no target", iterations=0, metrics={"travelled_m": 0.0})
    for _ in range(4):
        rotate_by(ctx, math.pi / 2, drive)
        if not drive.ok:
            return EpisodeOutcome("failed", failure_reason(drive.last), iterations=drive.steps)
    return EpisodeOutcome("completed", "rotated 360 degrees", iterations=drive.steps, metrics={"travelled_m": 0.0})
