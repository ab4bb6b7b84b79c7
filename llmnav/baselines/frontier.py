"""Frontier exploration + shortest path: explore with the robot's own LiDAR until a target is seen, then A*.

The robot starts knowing nothing but the extent of the world. It keeps a `grid.LidarMap` (unknown / free
/ occupied) filled by its LiDAR scans and repeats:

1. *Look*: integrate a scan, then turn in place in steps of ~90 % of the camera's horizontal field of view
   and run `Detector.detect()` after each turn, until an acceptable target of the task is detected
   (a `point` target counts as found once its cell is observed free in the map).
2. *Frontiers* (`llmnav.mapping.frontiers`): free cells next to unknown ones (4-neighbourhood), clustered
   8-connected; clusters smaller than `min_cluster_cells` are noise; cells near earlier frontier goals
   are struck off.
3. *Nearest*: one A* (Dijkstra, heuristic 0) from the robot over the known map settles the goal cell
   with the shortest path. Unknown cells are treated as *blocked* and inflated like obstacles (robot
   radius + margin): the robot plans only through space it has seen free and keeps its clearance from
   whatever may hide in the unknown, so its goals are the free cells just outside that inflation, next to
   a frontier.
4. *Drive*: follow the line-of-sight-shortcut path with `Motion.go_to` in legs of at most
   `waypoint_spacing_m`; after each leg a scan goes into the map and the detector looks for targets.
   The path runs through seen-free space only, so no LiDAR stop is armed (it would cost a scan every
   0.1 s); a bump into something the LiDAR cannot see (lower than its mount) is marked in the map, the
   robot backs off and plans again.

Once a target is detected, the final leg is the oracle's A* on the *true* grid from the current pose to
that target's approach point (`oracle.plan_to_targets`), driven the same way; then the robot faces it.
The run fails with its reason when no reachable frontier is left, or the frontier or sim-time budget is
spent. Reported `frontier_length_m`: the distance actually driven (exploration + final leg, ground truth).

Reference: B. Yamauchi, "A frontier-based approach for autonomous exploration", IEEE CIRA 1997.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, ClassVar, Literal

import numpy as np

from llmnav.baselines.drive import (
    Belief,
    Drive,
    drive_planned,
    drive_waypoints,
    face_point,
    failure_reason,
    log_action,
    rotate_by,
    run_untargeted,
)
from llmnav.core.declarations import Declarations, ReferencePath
from llmnav.core.geometry import Point
from llmnav.mapping.astar import astar, densify, shortcut
from llmnav.mapping.frontiers import frontier_clusters, goal_cells, sensed_grid
from llmnav.mapping.grid import (
    GridConfig,
    LidarMap,
    OccupancyGrid,
    margins_from,
    nearest_free_cell,
)
from llmnav.mapping.targets import OracleConfig, OraclePath, with_added_obstacles
from llmnav.planners.base import EpisodeContext, EpisodeOutcome, Information, Planner

if TYPE_CHECKING:
    from llmnav.core.geometry import Pose2D
    from llmnav.world.scenario import Target


@dataclass(frozen=True)
class FrontierConfig:
    """Exploration knobs and budgets."""

    min_cluster_cells: int = 8  # [cells] smaller frontier clusters are ignored (0.4 m at 0.05 m cells)
    min_goal_distance_m: float = 0.6  # [m] frontier cells closer than this to the robot are not goals
    visited_radius_m: float = 1.2  # [m] frontier cells this close to an earlier goal are struck off
    goal_band_m: float = 0.2  # [m] goals lie within inflation + this of a frontier cell
    start_snap_m: float = 0.5  # [m] how far the planner may snap the robot out of the inflation
    waypoint_spacing_m: float = 1.0  # [m] longest go_to leg while exploring (detections run after each)
    sweep_fov_fraction: float = 0.9  # share of the camera's horizontal FOV turned per sweep step
    bump_backoff_m: float = 0.15  # [m] move this far away from a collision
    bump_mark_radius_m: float = 0.2  # [m] disc marked occupied just beyond the body where it touched
    max_frontiers: int = 40  # frontier goals before giving up
    max_sim_time_s: float = 900.0  # [s] sim-time budget for the whole episode
    max_replans: int = 3  # [count] interrupted legs (bump, timeout) tolerated on the way to one frontier
    grid: GridConfig = field(default_factory=GridConfig)
    oracle: OracleConfig = field(default_factory=OracleConfig)


@dataclass
class _Found:
    """A detected acceptable target."""

    target: Target
    how: Literal["camera", "map"]


class _Explorer:
    """The state of one exploration episode (the planner itself stays stateless)."""

    def __init__(self, ctx: EpisodeContext, config: FrontierConfig) -> None:
        self.ctx = ctx
        self.config = config
        self.world = ctx.world
        self.robot = ctx.world.robot
        self.belief = Belief(ctx, mapping=True, resolution_m=config.grid.resolution_m)
        assert self.belief.map is not None  # asked for above
        self.map = self.belief.map
        self.geometry = self.map.geometry
        self.visited = np.zeros(self.geometry.shape, dtype=bool)
        self.inflation_m = self.robot.spec.radius_m + config.grid.margin_m  # [m]
        self.drive = Drive()
        self.frontiers = 0  # frontier goals chosen
        self.bumps = 0
        self.target_ids = {t.object for t in ctx.task.targets if t.object is not None}

    # --- sensing ------------------------------------------------------------------------------
    def scan_now(self) -> None:
        """One scan into the map at the believed pose (localized first, sensed), with the low scanner's."""
        self.belief.sense()

    def detect(self) -> _Found | None:
        """An acceptable target in view (camera), or a point target already seen free in the map."""
        for detection in self.world.detector.detect():
            if detection.object_id in self.target_ids:
                target = next(t for t in self.ctx.task.targets if t.object == detection.object_id)
                self.ctx.log.event(
                    "planner",
                    kind="frontier_detection",
                    object=detection.object_id,
                    distance_m=round(detection.distance_m, 3),
                    bearing_deg=round(detection.bearing_deg, 2),
                    pose=self.belief.pose().as_list(),
                )
                return _Found(target, "camera")
        for target in self.ctx.task.targets:
            if target.point is not None:
                cell = self.geometry.world_to_cell(*target.point)
                if self.geometry.contains(cell) and self.map.state[cell] == LidarMap.FREE:
                    return _Found(target, "map")
        return None

    def look(self) -> _Found | None:
        """Scan, then sweep the camera round in place, detecting after each turn."""
        self.scan_now()
        found = self.detect()
        if found is not None:
            return found
        camera = self.world.camera.config
        vertical = math.radians(camera.fov_deg)
        horizontal = 2.0 * math.atan(math.tan(vertical / 2.0) * camera.width / camera.height)  # [rad]
        turns = math.ceil(2.0 * math.pi / (self.config.sweep_fov_fraction * horizontal))
        for _ in range(turns - 1):  # the last turn would face the starting heading again
            rotate_by(self.ctx, 2.0 * math.pi / turns, self.drive)
            if not self.drive.ok:
                return None
            found = self.detect()
            if found is not None:
                return found
        self.scan_now()
        return None

    # --- planning -----------------------------------------------------------------------------
    def planning_grid(self, margin_m: float | None = None) -> OccupancyGrid:
        """The known map as a planning grid: occupied *and unknown* cells inflated, plus the bounds margin.

        (`llmnav.mapping.frontiers.sensed_grid`.) Inflated by the robot's radius plus `margin_m` [m]
        (default: the configured margin).
        """
        margin = self.config.grid.margin_m if margin_m is None else margin_m
        return sensed_grid(self.map, self.ctx.scenario.bounds, self.robot.spec.radius_m + margin)

    def frontier_goals(self, grid: OccupancyGrid, pose: Pose2D) -> np.ndarray:
        """Cells the robot may drive to in order to look past a frontier.

        Frontier clusters of `llmnav.mapping.frontiers` less the cells near earlier goals; since unknown
        space is inflated, the robot cannot stand on a frontier cell itself: its goals are the free cells
        within inflation + `goal_band_m` of a kept frontier cell (and not right under the robot).
        """
        labels = frontier_clusters(self.map, self.config.min_cluster_cells)
        labels[self.visited] = 0
        goals = goal_cells(labels, grid, grid.inflation_m + self.config.goal_band_m) > 0
        xs, ys = self.geometry.centres()
        near = np.hypot(xs - pose.x, ys - pose.y) < self.config.min_goal_distance_m
        return np.asarray(goals & ~near)

    def mark_visited(self, point: Point) -> None:
        """Strike off frontier cells around a goal the robot has been sent to (it looked from there)."""
        xs, ys = self.geometry.centres()
        self.visited |= np.hypot(xs - point[0], ys - point[1]) <= self.config.visited_radius_m

    def next_frontier(self) -> tuple[Point, list[Point]] | None:
        """The nearest frontier goal by path length on the known map and the waypoints to it.

        Planned with the configured clearance, else through narrower passages (`margins_from`).
        """
        for margin in margins_from(self.config.grid.margin_m):
            choice = self._frontier_path(self.planning_grid(margin))
            if choice is not None:
                return choice
        return None

    def _frontier_path(self, grid: OccupancyGrid) -> tuple[Point, list[Point]] | None:
        pose = self.belief.pose()
        blocked = grid.blocked
        goals = self.frontier_goals(grid, pose)
        if not goals.any():
            return None
        start = nearest_free_cell(blocked, self.geometry, pose.x, pose.y, self.config.start_snap_m)
        if start is None:
            return None
        path = astar(blocked, start, goals, resolution_m=self.geometry.resolution)
        if path is None:
            return None
        corners = [self.geometry.cell_to_world(*cell) for cell in shortcut(path.cells, blocked)]
        points = [(pose.x, pose.y), *corners[1:]] if len(corners) > 1 else [(pose.x, pose.y), *corners]
        goal = self.geometry.cell_to_world(*path.goal)
        return goal, densify(points, self.config.waypoint_spacing_m)[1:]

    # --- acting -------------------------------------------------------------------------------
    def bump_recovery(self) -> None:
        """After touching something the LiDAR missed (lower than its mount): map it, then back off."""
        self.bumps += 1
        pose = self.belief.pose()
        contacts = self.robot.contact_points()
        if contacts:  # the contact normal points from the obstacle at the robot
            _body, nx, ny, _dist = contacts[0]
            norm = math.hypot(nx, ny) or 1.0
            ux, uy = -nx / norm, -ny / norm
            if self.belief.localizer is not None:
                # The bumper senses the direction in the body frame (the simulator gives it in the world's):
                # carried into the believed frame through the body.
                turn = pose.yaw - self.robot.pose().yaw
                ux, uy = ux * math.cos(turn) - uy * math.sin(turn), ux * math.sin(turn) + uy * math.cos(turn)
        else:
            ux, uy = math.cos(pose.yaw), math.sin(pose.yaw)
        reach = self.robot.spec.radius_m + self.config.bump_mark_radius_m
        self.map.mark_occupied(pose.x + reach * ux, pose.y + reach * uy, self.config.bump_mark_radius_m)
        ahead = ux * math.cos(pose.yaw) + uy * math.sin(pose.yaw) >= 0.0
        backoff = -self.config.bump_backoff_m if ahead else self.config.bump_backoff_m
        result = self.world.motion.drive(backoff)
        self.drive.travelled_m += result.distance_m
        self.drive.steps += 1
        log_action(self.ctx, self.drive.steps, "FRONT" if backoff > 0 else "BACK", abs(backoff), result)

    def explore_to(self, waypoints: list[Point]) -> _Found | None:
        """Drive towards a frontier; after each waypoint add a scan to the map and look for targets."""
        tol = self.config.oracle.waypoint_tol_m
        for waypoint in waypoints:
            drive_waypoints(self.ctx, [waypoint], self.drive, self.belief, tol_m=tol, final_tol_m=tol)
            result = self.drive.last
            assert result is not None
            if result.collided:
                self.bump_recovery()
            self.scan_now()
            found = self.detect()
            if found is not None or not result.ok:
                return found
        return None

    def over_budget(self) -> str | None:
        """Why the exploration must stop, if it must."""
        if self.frontiers >= self.config.max_frontiers:
            return f"exploration budget spent ({self.frontiers} frontiers) without detecting a target"
        if self.world.sim_time >= self.config.max_sim_time_s:
            return f"exploration budget spent ({self.world.sim_time:.0f} s sim time) without detecting a target"
        return None

    def metrics(self, final_leg: float | None = None) -> dict[str, float | int]:
        """Numbers for summary.json."""
        out: dict[str, float | int] = {
            "frontier_length_m": round(self.drive.travelled_m, 4),
            "frontiers_visited": self.frontiers,
            "bumps": self.bumps,
            "known_fraction": round(float(1.0 - self.map.unknown.mean()), 4),
        }
        if final_leg is not None:
            out["final_leg_planned_m"] = round(final_leg, 4)
        return out

    # --- the episode --------------------------------------------------------------------------
    def run(self) -> EpisodeOutcome:
        """Explore until a target is detected, then drive the shortest path to it."""
        found = self.look()
        replans = 0
        while found is None:
            reason = self.over_budget()
            if reason is not None:
                return self.fail(reason)
            choice = self.next_frontier()
            if choice is None:
                return self.fail("no reachable frontier left and no target detected")
            goal, waypoints = choice
            self.frontiers += 1
            self.ctx.log.event(
                "planner",
                kind="frontier_goal",
                goal=[round(goal[0], 3), round(goal[1], 3)],
                waypoints=[[round(x, 3), round(y, 3)] for x, y in waypoints],
                known_fraction=round(float(1.0 - self.map.unknown.mean()), 4),
            )
            found = self.explore_to(waypoints)
            last = self.drive.last
            interrupted = last is not None and not last.ok
            if last is not None and last.collided:
                self.mark_visited(goal)  # something unseen lies there: do not insist on this goal
            if interrupted and replans < self.config.max_replans and found is None:
                replans += 1  # stopped short (bump, timeout): choose again; the same goal may remain
                self.scan_now()
                continue
            replans = 0
            self.mark_visited(goal)
            if found is None:
                found = self.look()
        return self.finish(found)

    def finish(self, found: _Found) -> EpisodeOutcome:
        """Final leg: A* on the true grid to the detected target's approach point, then face it."""
        ctx = self.ctx
        scenario = with_added_obstacles(ctx.scenario, ctx.options.obstacles)

        def on_path(path: OraclePath, _attempt: int) -> None:
            ctx.log.event(
                "planner",
                kind="frontier_final_leg",
                target=found.target.object or list(found.target.point or ()),
                found_by=found.how,
                length_m=round(path.length_m, 3),
                waypoints=[[round(x, 3), round(y, 3)] for x, y in path.waypoints],
            )

        self.drive.last = None
        oracle = replace(self.config.oracle, grid=self.config.grid)  # the final leg plans on the explorer's grid rules
        path = drive_planned(ctx, scenario, [found.target], oracle, self.drive, self.belief, on_path=on_path)
        if path is None:
            return self.fail(f"target {found.target.object or found.target.point} detected but unreachable")
        if self.drive.ok:
            face_point(ctx, path.target_point, self.drive, self.belief)
        if not self.drive.ok:
            return self.fail(failure_reason(self.drive.last), path.length_m)
        return EpisodeOutcome(
            "completed", "reached target", iterations=self.drive.steps, metrics=self.metrics(path.length_m)
        )

    def fail(self, reason: str, final_leg: float | None = None) -> EpisodeOutcome:
        """End the episode as failed."""
        return EpisodeOutcome("failed", reason, iterations=self.drive.steps, metrics=self.metrics(final_leg))


class FrontierPlanner(Planner):
    """Frontier exploration on the robot's own LiDAR map, then the shortest path to the detected target."""

    name: ClassVar[str] = "frontier"
    needs_backend: ClassVar[bool] = False
    # explores its own map, then takes the true grid's path to the target; sensed, its pose is odometry
    # corrected by scan matching (the true map stays its final leg's)
    information_modes: ClassVar[tuple[Information, ...]] = ("oracle", "sensed")
    knows_map: ClassVar[bool] = True
    # Explores with no map and no model: the path table shows every other run's length against its own.
    declares: ClassVar[Declarations] = Declarations(reference_path=ReferencePath("frontier", "Frontier"))

    def __init__(self, config: FrontierConfig | None = None) -> None:
        self.config = config or FrontierConfig()

    def run(self, ctx: EpisodeContext) -> EpisodeOutcome:
        """Explore, detect, drive; tasks without targets behave as for the oracle."""
        if not ctx.task.targets:
            return run_untargeted(ctx, Drive())
        return _Explorer(ctx, self.config).run()
