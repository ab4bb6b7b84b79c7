"""Carrying out the hybrid planner's chosen option: A* legs through the shared leg driver, or a full turn.

Paths are planned on the roomiest planning grid that has one (falling back to the plain grid). A robot
standing inside the wall clearance first steps out to the nearest free cell. Each straight leg, at most
`leg_max_m` long, is turned toward first (so the LiDAR sees it), then driven by
`llmnav.guard.legs.drive_leg`: the motion layer's own check judges it, and a refused leg ends the option
(the robot has not moved; the model is told, and the same option then plans around what was seen from
where the robot really stands). Exploring ends early when something the task names comes into view, so
the model decides again with the new information. Each option is logged as one `action` event.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

from llmnav.core.geometry import Point, Pose2D
from llmnav.guard.legs import Action, drive_leg
from llmnav.mapping.astar import densify
from llmnav.mapping.grid import inflate, nearest_free_cell
from llmnav.mapping.paths import SNAP_M, plan_path
from llmnav.planners.hybrid.memory import Memory, believed_pose, in_odometry_frame, look

if TYPE_CHECKING:
    from llmnav.mapping.grid import LidarMap, OccupancyGrid
    from llmnav.nav.localize import Match
    from llmnav.planners.base import EpisodeContext
    from llmnav.planners.hybrid.config import HybridConfig
    from llmnav.planners.hybrid.menu import Option
    from llmnav.sim.motion import MotionResult
    from llmnav.sim.sensors import LidarScan


@dataclass(frozen=True)
class Executed:
    """What carrying out one option did."""

    result: str  # the result line the model reads next
    vetoes: int = 0  # legs the motion layer refused
    collided: bool = False
    saw_new: bool = False  # new objects came into view: the menu changed, even if the robot did not move


@dataclass(frozen=True)
class Executor:
    """Carries out options in one episode."""

    ctx: EpisodeContext
    cfg: HybridConfig
    lidar_map: LidarMap
    memory: Memory

    def run(self, grids: list[OccupancyGrid], option: Option, step: int) -> Executed:
        """Carry out `option` (not Finish); `grids` are the planning grids, roomiest first."""
        if option.kind == "scan":
            return self._scan(option, step)
        assert option.goal is not None
        before = self._believed()
        plans = (plan_legs(grid, before, option.goal, self.cfg.leg_max_m) for grid in grids)
        legs = next((plan for plan in plans if plan is not None), None)
        if legs is None:
            return Executed(f"no collision-free path ({option.goal_name})")
        for x, y in legs:
            result = self._leg(x, y, step)
            if result.collided:
                self._log(step, option, before, result)
                return Executed(f"collided with {result.collision_with or 'an obstacle'}", collided=True)
            if result.veto is not None:
                self._log(step, option, before, result)
                return Executed(self._refused(option, result.veto), vetoes=1)
            came = look(self.ctx, self.memory)
            # Exploring stops for what the task names (relevance order), or for anything new (neutral order,
            # where nothing is matched against the task): the model then decides with the new information.
            wanted = self.memory.wanted
            if option.kind == "frontier" and (came & wanted or (came and not wanted)):
                self._log(step, option, before, result)
                return Executed("stopped exploring: new objects in view", saw_new=True)
        return self._arrive(option, before, step)

    def sense(self, scan: LidarScan) -> Pose2D:
        """Localize on `scan` (sensed), then map it and the low scanner's returns at the pose believed then.

        Sensed, each scan reports the believed pose as a `localize` event (with the match when a localizer
        runs), which the summary's `pose_error_m` scores against the true pose.
        """
        ctx, memory = self.ctx, self.memory
        if ctx.information == "sensed":
            match = None
            if memory.localizer is not None:
                match = memory.localizer.update(ctx.world.robot.odom(), scan, self.lidar_map)
            self.report_pose(match)
        pose = self._believed()
        self.lidar_map.integrate(pose, scan)
        self.lidar_map.mark_hits(pose, ctx.world.low_lidar.scan())
        return pose

    def report_pose(self, match: Match | None = None) -> None:
        """Log the believed pose as a `localize` event (sensed only), with what the match concluded."""
        if self.ctx.information != "sensed":
            return
        fields: dict[str, Any] = {"pose": self._believed().as_list()}
        if match is not None:
            fields |= match.fields()
        self.ctx.event("localize", **fields)

    def _believed(self) -> Pose2D:
        return believed_pose(self.ctx, self.memory)

    # --- the steps ----------------------------------------------------------------------------------
    def _scan(self, option: Option, step: int) -> Executed:
        """Four quarter turns, looking after each (and localizing, where a localizer runs)."""
        before = self._believed()
        new, result = self._turn_looking()
        self._log(step, option, before, result, command="SCAN", parameters=360.0)
        return Executed("looked around, " + ("new objects in view" if new else "nothing new"), collided=result.collided)

    def _turn_looking(self) -> tuple[bool, MotionResult]:
        """A full turn in quarters, looking after each; whether anything new came into view, the last turn."""
        world = self.ctx.world
        at = self._believed()
        new = False
        for _ in range(4):
            result = world.motion.rotate(math.pi / 2)
            if self.memory.localizer is not None:  # a turn in place drifts most: correct it quarter by quarter
                self.sense(world.lidar.scan())
            new |= bool(look(self.ctx, self.memory))
            if result.collided:
                break
        self.memory.scans += 1
        self.memory.scanned_at = (at.x, at.y)
        return new, result

    def _leg(self, x: float, y: float, step: int) -> MotionResult:
        """Turn toward the leg (the LiDAR then sees it), map the scan it is checked on, drive it."""
        world = self.ctx.world
        turn = self._believed().bearing_to(x, y)
        if abs(turn) > self.cfg.turn_first_rad:
            world.motion.rotate(turn)
        # What the leg is checked on goes into the map, so a plan after a refusal routes around it.
        self.sense(world.lidar.scan())
        # The leg's end in the frame go_to drives in (the believed frame, once the localizer corrects it).
        goal_x, goal_y = in_odometry_frame(self.ctx, self.memory, x, y)
        result = drive_leg(world, goal_x, goal_y, step=step, obstacle_stop_m=self.cfg.obstacle_stop_m)
        if result.stopped_reason == "monitor":  # what stopped it goes into the map too
            self.sense(world.lidar.scan())
        return result

    def _arrive(self, option: Option, before: Pose2D, step: int) -> Executed:
        """Face what the option went to, note the visit, say how close the robot got.

        At an explored edge the robot turns a full circle, looking (as frontier exploration does): the
        LiDAR maps all around on the way, the camera sees only ahead, so a room driven into and out of was
        mapped (its frontiers gone) without the camera ever facing most of it. Measured on generated
        flats: 7 of 9 `not_found` episodes with oracle answers passed within 2-5 m of a target they never
        faced.
        """
        memory = self.memory
        if option.face is not None:
            self.ctx.world.motion.rotate(self._believed().bearing_to(*option.face))
        if option.landmark_id is not None:
            memory.visited.add(option.landmark_id)
        new = False
        if option.kind == "frontier" and option.goal is not None:
            memory.reached_frontier(option.goal)
            new = self._turn_looking()[0]
        after = self._believed()
        self._log(step, option, before, None)
        seen = ", looked around: new objects in view" if new else ""
        if option.goal is not None and after.distance_to(*option.goal) > self.cfg.arrived_m:
            return Executed(f"stopped {after.distance_to(*option.goal):.1f} m short ({option.goal_name}){seen}")
        return Executed(f"reached {option.goal_name}{seen}")

    def _refused(self, option: Option, reason: str) -> str:
        """What a vetoed leg means for the menu, as the result line says it.

        Near the landmark the refused spot is as close as the robot may safely get (its goal point hugs
        the object): it counts as arrival. Elsewhere the next plan avoids what the LiDAR saw; a landmark
        refused twice from the same spot is dropped from the menu, since the detour did not help.
        """
        memory, here = self.memory, self._believed()
        landmark = option.landmark_id
        near = option.face is not None and here.distance_to(*option.face) <= self.cfg.stop_within_m
        if landmark is not None and near:
            memory.closest[landmark] = (here.x, here.y)
            memory.visited.add(landmark)
            return f"as close to {option.goal_name} as is safe"
        if landmark is not None:
            again = memory.refused.get(landmark)
            if again is not None and here.distance_to(*again) <= 0.1:
                memory.unreachable.add(landmark)
            memory.refused[landmark] = (here.x, here.y)
        # The model is told that retrying is meaningful: the next plan avoids what blocked this one.
        return f"safety stop ({reason}); obstacle mapped, same choice detours"

    def _log(
        self,
        step: int,
        option: Option,
        before: Pose2D,
        result: MotionResult | None,
        *,
        command: str = "GOTO",
        parameters: float | None = None,
    ) -> None:
        """The option as one `action` event: from where it started to where the planner believes it ended."""
        after = self._believed()
        travelled = round(before.distance_to(after.x, after.y), 3)
        Action(
            step,
            command,
            travelled if parameters is None else parameters,
            before,
            after,
            collided=bool(result and result.collided),
            collision_with=result.collision_with if result else None,
            stopped_reason=result.stopped_reason if result else None,
            veto=result.veto if result else None,
            option=option.text,
        ).log(self.ctx.log)


def plan_legs(grid: OccupancyGrid, start: Pose2D, goal: Point, leg_max_m: float) -> list[Point] | None:
    """A* legs from the robot to the goal, no longer than `leg_max_m` [m] each.

    A robot standing inside the inflation (beside a wall) first steps out to the nearest free cell:
    a long leg along the wall from there would graze it, and the veto would refuse it every time.
    """
    first: list[Point] = []
    origin = (start.x, start.y)
    if not grid.is_free(*origin):
        cell = nearest_free_cell(grid.blocked, grid.geometry, start.x, start.y, SNAP_M)
        if cell is None:
            return None
        origin = grid.geometry.cell_to_world(*cell)
        first = [origin]
    path = plan_path(grid, origin, goal)
    if path is None:
        return None
    return first + densify([origin, *path[1:]], leg_max_m)[1:]


def with_seen_obstacles(grid: OccupancyGrid, lidar_map: LidarMap, near_known: Any, depth_m: float) -> OccupancyGrid:
    """The grid plus the LiDAR hits away from every known solid (`near_known`), inflated alike.

    The extra `depth_m` [m] stands for the obstacle's back, which the LiDAR has not seen.
    """
    unexpected = lidar_map.occupied & ~near_known
    if not unexpected.any():
        return grid
    return replace(
        grid,
        occupied=grid.occupied | unexpected,
        blocked=grid.blocked | inflate(unexpected, grid.inflation_m + depth_m, grid.geometry.resolution),
    )
