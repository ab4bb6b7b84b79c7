"""Oracle baseline: drive the shortest collision-free path to the nearest target approach point.

The oracle knows the whole map, including boxes dropped at run time: `llmnav.baselines.drive.plan_to`
plans it (A* on the true inflated grid to the 1.5–2.5 m approach band, see there). `OraclePlanner` drives
that path with the guarded motion layer's `go_to`, waypoint by waypoint, then turns to face the target.
A leg the motion layer refuses (or the collision monitor stops) is planned again from the true pose around
the return that blocked it, marked on the map (`drive_planned`); when the map is too tight for its
clearance, it plans through narrower passages, which the leg check and the monitor still guard.
Tasks without targets: a `rotate` task turns 360°, an `explore` task ends at once.
With `sensed` information the map and the targets stay the oracle's, but its pose is odometry corrected by
scan matching against the LiDAR map it builds on the way (`llmnav.baselines.drive.Belief`).
"""

from __future__ import annotations

from typing import ClassVar

from llmnav.baselines.drive import Belief, Drive, drive_planned, face_point, failure_reason, run_untargeted
from llmnav.mapping.targets import OracleConfig, OraclePath, with_added_obstacles
from llmnav.planners.base import EpisodeContext, EpisodeOutcome, Information, Planner


class OraclePlanner(Planner):
    """Drives the oracle's shortest path in the simulator and faces the target."""

    name: ClassVar[str] = "oracle"
    needs_backend: ClassVar[bool] = False
    information_modes: ClassVar[tuple[Information, ...]] = ("oracle", "sensed")
    knows_map: ClassVar[bool] = True

    def __init__(self, config: OracleConfig | None = None) -> None:
        self.config = config or OracleConfig()

    def run(self, ctx: EpisodeContext) -> EpisodeOutcome:
        """Plan from the current pose, drive the path, turn to the target; plan around a refused leg."""
        drive, belief = Drive(), Belief(ctx)
        if not ctx.task.targets:
            return run_untargeted(ctx, drive)
        # The oracle knows everything, including boxes dropped at run time.
        scenario = with_added_obstacles(ctx.scenario, ctx.options.obstacles)
        metrics: dict[str, float] = {}

        def on_path(path: OraclePath, attempt: int) -> None:
            _log_path(ctx, path)
            if attempt == 0:  # the yardstick is the first plan's, from the start pose
                metrics["oracle_length_m"] = round(path.length_m, 4)
                metrics["oracle_grid_length_m"] = round(path.grid_length_m, 4)

        path = drive_planned(ctx, scenario, ctx.task.targets, self.config, drive, belief, on_path=on_path)
        if path is None:
            ctx.log.event("planner", kind="oracle_path", found=False)
            return EpisodeOutcome("failed", "no collision-free path to any target", metrics=metrics)
        if drive.ok:
            face_point(ctx, path.target_point, drive, belief)
        metrics["travelled_m"] = round(drive.travelled_m, 4)
        if not drive.ok:
            return EpisodeOutcome("failed", failure_reason(drive.last), iterations=drive.steps, metrics=metrics)
        return EpisodeOutcome("completed", "reached target", iterations=drive.steps, metrics=metrics)


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
