"""Oracle baseline: drive the shortest collision-free path to the nearest target approach point.

The oracle knows the whole map, including boxes dropped at run time: `llmnav.mapping.targets.oracle_path`
plans it (A* on the true inflated grid to the 1.5–2.5 m approach band, see there). `OraclePlanner` drives
that path with the guarded motion layer's `go_to`, waypoint by waypoint, then turns to face the target.
A leg the motion layer refuses is planned again from the true pose with more clearance (twice at most).
Tasks without targets: a `rotate` task turns 360°, an `explore` task ends at once.
"""

from __future__ import annotations

from dataclasses import replace
from typing import ClassVar

from llmnav.baselines.drive import Drive, drive_waypoints, face_point, failure_reason, run_untargeted
from llmnav.mapping.targets import OracleConfig, OraclePath, oracle_path, with_added_obstacles
from llmnav.planners.base import EpisodeContext, EpisodeOutcome, Information, Planner
from llmnav.scenario import Scenario


class OraclePlanner(Planner):
    """Drives the oracle's shortest path in the simulator and faces the target."""

    name: ClassVar[str] = "oracle"
    needs_backend: ClassVar[bool] = False
    information_modes: ClassVar[tuple[Information, ...]] = ("oracle",)

    replans_after_veto: ClassVar[int] = 2  # plans from the true pose after a leg the motion layer refused
    veto_margin_step_m: ClassVar[float] = 0.1  # [m] more clearance on each such plan
    narrow_margins_m: ClassVar[tuple[float, ...]] = (0.05, 0.02)  # [m] clearances tried when none fits

    def __init__(self, config: OracleConfig | None = None) -> None:
        self.config = config or OracleConfig()

    def _plan(self, ctx: EpisodeContext, scenario: Scenario, config: OracleConfig) -> OraclePath | None:
        """The shortest path with the configured clearance, else through narrower passages.

        A doorway of the robot's width + 0.3 m leaves no room at the full margin; with less, the leg check
        and the collision monitor still keep the robot off the frame.
        """
        pose = ctx.world.robot.pose()
        for margin in (config.grid.margin_m, *(m for m in self.narrow_margins_m if m < config.grid.margin_m)):
            path = oracle_path(scenario, ctx.task, pose, config=_narrower(config, margin))
            if path is not None:
                return path
        return None

    def run(self, ctx: EpisodeContext) -> EpisodeOutcome:
        """Plan from the current pose, drive the path, turn to the target; replan wider after a vetoed leg."""
        drive = Drive()
        if not ctx.task.targets:
            return run_untargeted(ctx, drive)
        # The oracle knows everything, including boxes dropped at run time.
        scenario = with_added_obstacles(ctx.scenario, ctx.options.obstacles)
        metrics: dict[str, float] = {}
        config = self.config
        face = (0.0, 0.0)  # what to face at the end: the target of the last plan
        for attempt in range(1 + self.replans_after_veto):
            path = self._plan(ctx, scenario, config)
            if path is None:
                ctx.log.event("planner", kind="oracle_path", found=False)
                return EpisodeOutcome("failed", "no collision-free path to any target", metrics=metrics)
            _log_path(ctx, path)
            face = path.target_point
            if attempt == 0:  # the yardstick is the first plan's, from the start pose
                metrics["oracle_length_m"] = round(path.length_m, 4)
                metrics["oracle_grid_length_m"] = round(path.grid_length_m, 4)
            drive_waypoints(ctx, path.waypoints, drive, tol_m=config.waypoint_tol_m, final_tol_m=config.final_tol_m)
            if drive.ok or drive.last is None or drive.last.veto is None:
                break
            # The leg check judged a leg the grid called clear (a leg starts off its corner, cells are
            # coarse): plan again from here, keeping more room.
            grid = replace(config.grid, margin_m=config.grid.margin_m + self.veto_margin_step_m)
            config = replace(config, grid=grid)
        if drive.ok:
            face_point(ctx, face, drive)
        metrics["travelled_m"] = round(drive.travelled_m, 4)
        if not drive.ok:
            return EpisodeOutcome("failed", failure_reason(drive.last), iterations=drive.steps, metrics=metrics)
        return EpisodeOutcome("completed", "reached target", iterations=drive.steps, metrics=metrics)


def _narrower(config: OracleConfig, margin_m: float) -> OracleConfig:
    return replace(config, grid=replace(config.grid, margin_m=margin_m))


def _log_path(ctx: EpisodeContext, path: OraclePath) -> None:
    ctx.log.event(
        "planner",
        kind="oracle_path",
        found=True,
        target=path.target.object or list(path.target.point or ()),
        approach=[round(v, 3) for v in path.approach],
        length_m=round(path.length_m, 3),
        grid_length_m=round(path.grid_length_m, 3),
        waypoints=[[round(x, 3), round(y, 3)] for x, y in path.waypoints],
    )
