"""Executing waypoint plans in the simulator (source B): the planner that grounds, plans, follows and replans.

Per leg of the command: ground the target, plan (`plan.generate_plan`), follow every segment through the
guarded motion layer with the P-controller (0.4 m/s, 2.0 rad/s, 0.1 m, 0.087 rad) and its obstacle stops
(0.5 m within ±15° ahead, emergency below 0.35 m); a segment the layer vetoes (something the map lacks
on it) or a stop leads to a replan from the current pose around what was seen, at most `max_replans`
times with a cooldown in simulated time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar

from llmnav.core.chat import ChatRequest, ChatResult
from llmnav.core.declarations import Column, Declarations, ScoreTable
from llmnav.core.geometry import Point, Pose2D
from llmnav.errors import BadInputError, InvalidActionError
from llmnav.guard.legs import drive_leg
from llmnav.planners.base import (
    EpisodeContext,
    EpisodeOutcome,
    Information,
    Planner,
    StepInfo,
    decides_by_scores,
    fallback_mark,
)
from llmnav.planners.observe import call_model
from llmnav.planners.waypoints.planner.ground import ground_target
from llmnav.planners.waypoints.planner.options import WaypointOptions
from llmnav.planners.waypoints.planner.plan import Attempt, PlanningClock, PlanResult, generate_plan
from llmnav.planners.waypoints.planner.validate import validate_waypoints

if TYPE_CHECKING:
    from llmnav.core.chat import AnswerKey
    from llmnav.planners.base import GroundTruth
    from llmnav.sim.motion import MotionResult
    from llmnav.world.scenario import Scenario


@dataclass(frozen=True)
class WaypointConfig:
    """Execution constants of the waypoint source."""

    linear_speed: float = 0.4  # [m/s]
    angular_speed: float = 2.0  # [rad/s]
    reach_tol_m: float = 0.1  # [m]
    angle_tol_rad: float = 0.087  # [rad] rotate in place above it
    critical_m: float = 0.5  # [m] obstacle stop within ±15° ahead
    emergency_m: float = 0.35  # [m]
    # An obstacle the LiDAR stopped for is assumed a disc of this radius whose near edge is the closest
    # return (a 0.5 m box seen head-on lies within 0.43 m of that centre).
    obstacle_radius_m: float = 0.35  # [m]
    obstacle_margin_m: float = 0.1  # [m] clearance kept from it beyond the robot's radius


# Source B, Tables 1–3: a row per command and one averaged over them. A run whose plan failed drove nothing:
# its execution time and path are left out of the means (the source leaves failed plans out of its averages),
# not counted as 0 s and 0 m. Replans are counts, as the source gives them. `llmnav score --table
# waypoints-legs` has one row per leg of a route (`legs` below).
WAYPOINT_TABLE = ScoreTable(
    name="waypoints",
    title="Waypoint planner (waypoint source, Tables 1–3 style)",
    columns=(
        Column("planning_time_s", "Planning (s)", bounds=(0.0, None)),
        Column("execution_time_s", "Execution (s)", unless="plan_failed", bounds=(0.0, None)),
        Column("path_length_m", "Path (m)", source="summary", unless="plan_failed", bounds=(0.0, None)),
        Column("wgsr", "WGSR (%)", digits=1, bounds=(0.0, 100.0)),
        Column("collision_events", "Collision events", digits=1, bounds=(0.0, None)),
        Column("replans", "Replans", digits=1, bounds=(0.0, None)),
        Column("successes", "Success", aggregate="rate", source="summary", path="success"),
    ),
    marker="wgsr",
    rows="command",
    average_row=True,
    note="Execution and Path leave out runs whose plan failed ('failed' when every run's did); Replans: count",
)

# What a leg record (`legs` in the planner metrics) counts from the episode's running totals.
LEG_COUNTERS = ("planning_time_s", "generations", "valid_generations", "execution_time_s", "driven_m",
                "collision_events")  # fmt: skip


@dataclass(frozen=True)
class _LegStart:
    """Where a leg of the command began: its command, target, true pose and the running totals then."""

    command: str
    target_id: str
    pose: Pose2D
    counters: dict[str, float]


def map_to_odom(point: Point, start_map: Pose2D, start_odom: Pose2D) -> Point:
    """A map-frame point in the odometry frame: rotate by the frame offset, then translate."""
    dtheta = start_odom.yaw - start_map.yaw
    dx, dy = point[0] - start_map.x, point[1] - start_map.y
    c, s = math.cos(dtheta), math.sin(dtheta)
    return (start_odom.x + c * dx - s * dy, start_odom.y + s * dx + c * dy)


class WaypointPlanner(Planner):
    """Source B on the simulator; several targets in sequence with repeated `--task`."""

    name = "waypoints"
    needs_backend = True
    # A decision is one leg of the command: grounding, plan generations, replans, each asking the model.
    declares = Declarations(score_tables=(WAYPOINT_TABLE,), decision_noun="Leg", asks_model_every_decision=True)
    Options = WaypointOptions
    options = frozenset({"temperature"})
    information_modes: ClassVar[tuple[Information, ...]] = ("map",)  # the corridor rectangles and object positions
    grid_factors = ("decide",)

    def __init__(self, config: WaypointConfig | None = None) -> None:
        self.cfg = config or WaypointConfig()

    @staticmethod
    def templates(options: WaypointOptions) -> list[str]:
        """Prompt templates this planner renders (their hashes go into the run config)."""
        return ["ground_system", "ground_user", "waypoints_system", "waypoints_user", "waypoints_feedback"]

    @staticmethod
    def check_scenario(scenario: Scenario) -> None:
        """Bad input before any run folder or model: waypoints are validated against corridors."""
        if not scenario.corridors:
            raise BadInputError(
                f"--planner waypoints: scenario '{scenario.name}' publishes no corridors; the waypoint "
                "planner needs them"
            )

    def oracle_answers(self, truth: GroundTruth, options: WaypointOptions) -> AnswerKey:
        """Plans from the true pose through the junction points to the true target, beyond the emergency stop."""
        # deferred: the answer key brings numpy and yaml (about 0.1 s), only with an oracle
        from llmnav.planners.waypoints.planner.oracle import WaypointAnswerKey

        return WaypointAnswerKey(truth, keep_clear_m=self.cfg.emergency_m)

    def run(self, ctx: EpisodeContext) -> EpisodeOutcome:
        """Ground, plan, validate, execute, replan — per leg of the command sequence."""
        # deferred: numpy and yaml (about 0.1 s) load only when an episode runs
        from llmnav.mapping.grid import build_grid
        from llmnav.world.tasks import sequence_legs

        world, scenario, opts, cfg = ctx.world, ctx.scenario, ctx.options, self.cfg
        if not scenario.corridors:
            raise InvalidActionError(
                f"scenario '{scenario.name}' publishes no corridors; the waypoint planner needs them"
            )
        grid = build_grid(scenario)
        rules = scenario.waypoint_rules
        # a segment must clear an obstacle seen on the way by its assumed size, the robot's radius and a margin
        clearance = cfg.obstacle_radius_m + world.robot.spec.radius_m + cfg.obstacle_margin_m  # [m]
        step = 0
        metrics: dict[str, Any] = {
            "planning_time_s": 0.0,
            "execution_time_s": 0.0,
            "generations": 0,
            "valid_generations": 0,
            "collision_events": 0,
            "vetoed_segments": 0,
            "replans": 0,
            "driven_m": 0.0,  # [m] ground truth, summed over the executed segments (source B's path length)
            "plan_failed": False,  # a leg ended without a valid plan: nothing was driven for it
            "legs": [],
        }

        def call(request: ChatRequest, purpose: str) -> ChatResult:
            return call_model(ctx, request, purpose=purpose, step=step)

        # Free text that names no object is grounded by scores where the backend can (`--decide`).
        scores = decides_by_scores(ctx.options, ctx.backend)
        score = (lambda request: ctx.score(request, step)) if scores else None
        mark = fallback_mark(ctx.options.decide, "score" if scores else "generate")
        if mark:
            ctx.event("planner", decide="generate", requested=ctx.options.decide, **mark)

        def note(kind: str, **fields: Any) -> None:
            ctx.log.sim_time = world.sim_time
            ctx.log.event("planner", kind=kind, step=step, **fields)

        def log_attempt(attempt: Attempt) -> None:
            note(
                "waypoint_attempt",
                attempt=attempt.number,
                points=attempt.points,
                valid=attempt.valid,
                problems=attempt.problems,
                latency_s=attempt.latency_s,
            )

        last_replan = -math.inf  # [s] sim time of the previous replan
        preset = [(float(x), float(y)) for x, y in opts.preset_waypoints]
        for leg in sequence_legs(scenario, ctx.task):
            step += 1
            clock = PlanningClock(call)
            near = preset[-1] if preset else None
            target = ground_target(
                scenario,
                leg,
                clock,
                near=near,
                tolerance_m=rules.target_tolerance_m,
                step=step,
                on_event=ctx.event,
                score=score,
            )
            grounding_s = clock.elapsed_s()  # [s] counted in this leg's first planning time
            note("grounding", command=leg.text, target=target.id)
            seen: list[Point] = []
            replans = 0
            opened = _LegStart(leg.text, target.id, world.robot.pose(), {k: metrics[k] for k in LEG_COUNTERS})
            while True:
                start = world.robot.pose()
                if preset:  # `llmnav plan --execute`: the plan was made already; it is validated again
                    problems = validate_waypoints(preset, (start.x, start.y), target.goal_point, scenario, grid, rules)
                    attempt = Attempt(1, 0.0, preset, problems, "bounds" if problems else "ok")
                    plan = PlanResult(target.id, target.goal_point, [attempt])
                    log_attempt(attempt)
                    error = "\n".join(problems) or None
                    ctx.event("guard", step=step, attempt=1, outcome=attempt.outcome, error=error, purpose="preset")
                    preset = []
                else:
                    plan = generate_plan(
                        scenario,
                        target,
                        start,
                        call,
                        max_generations=opts.max_generations,
                        grid=grid,
                        temperature=opts.temperature,
                        seed=opts.seed,
                        seen_obstacles=seen,
                        obstacle_clearance_m=clearance,
                        on_attempt=log_attempt,
                        step=step,
                        on_event=ctx.event,
                    )
                plan.planning_time_s += grounding_s
                grounding_s = 0.0
                self._count(metrics, plan)
                waypoints = plan.waypoints
                if waypoints is None:
                    metrics["plan_failed"] = True
                    return self._leg_failed(
                        ctx,
                        metrics,
                        opened,
                        replans,
                        f"no valid waypoints for {target.label} after {len(plan.attempts)} generations",
                        step,
                        plan_failed=True,
                    )
                ctx.view.on_step(
                    StepInfo(
                        step,
                        f"plan to {target.label}: {len(waypoints)} waypoints",
                        latency_s=plan.planning_time_s,
                        json_retries=len(plan.attempts) - 1,
                    )
                )
                stop, last = self._execute(ctx, waypoints, metrics, step, start)
                if stop is None:
                    break
                if stop == "collision":
                    return self._leg_failed(
                        ctx, metrics, opened, replans, "collided while following waypoints", step, collided=True
                    )
                obstacle: Point | None = None
                if stop in ("obstacle", "emergency"):  # a LiDAR reading below the stop distance
                    metrics["collision_events"] += 1
                    obstacle = self._obstacle_ahead(ctx, wide=stop == "emergency")
                elif stop in ("vetoed", "monitor"):  # the motion layer refused the segment or stopped it on the way
                    metrics["vetoed_segments"] += 1
                    obstacle = self._obstacle_at(ctx, last.veto_hit if last is not None else None)
                if obstacle is not None:
                    seen.append(obstacle)
                if replans >= opts.max_replans:
                    return self._leg_failed(
                        ctx,
                        metrics,
                        opened,
                        replans,
                        f"path to {target.label} still blocked ({stop}) after {replans} replans",
                        step,
                    )
                wait = opts.replan_cooldown_s - (world.sim_time - last_replan)  # [s]
                if wait > 0:  # cooldown between replans, in simulated time, standing still
                    world.motion.velocity_tick(0.0, 0.0, wait)
                replans += 1
                metrics["replans"] += 1
                last_replan = world.sim_time
                here = world.robot.pose()
                note(
                    "replan",
                    reason=stop,
                    number=replans,
                    pose=here.as_list(),
                    obstacle=None if obstacle is None else [round(obstacle[0], 3), round(obstacle[1], 3)],
                    waited_s=round(max(wait, 0.0), 3),
                )
            metrics["legs"].append(self._leg_record(ctx, metrics, opened, replans, reached=True))
        return self._end(metrics, "completed", "reached every target", step)

    def _execute(
        self,
        ctx: EpisodeContext,
        waypoints: list[Point],
        metrics: dict[str, Any],
        step: int,
        start_map: Pose2D,
    ) -> tuple[str | None, MotionResult | None]:
        """Follow the waypoints; (None, last result) when all are reached, else (the stop reason, its result).

        Every segment is a leg of `llmnav.guard.legs.drive_leg`: the motion layer vetoes it before the robot
        moves when the LiDAR sees something on it (the map-based validation cannot know what the map lacks).
        """
        world, cfg = ctx.world, self.cfg
        start_odom = world.robot.odom()
        t0 = world.sim_time
        result: MotionResult | None = None
        try:
            for index, point in enumerate(waypoints, start=1):
                x, y = map_to_odom(point, start_map, start_odom)
                result = drive_leg(
                    world,
                    x,
                    y,
                    step=step,
                    log=ctx.log,
                    command="WAYPOINT",
                    parameters=[round(point[0], 3), round(point[1], 3)],
                    index=index,
                    tol_m=cfg.reach_tol_m,
                    ang_tol=cfg.angle_tol_rad,
                    v_max=cfg.linear_speed,
                    w_max=cfg.angular_speed,
                    obstacle_stop_m=cfg.critical_m,
                    emergency_stop_m=cfg.emergency_m,
                )
                metrics["driven_m"] += result.distance_m
                if result.collided:
                    return "collision", result
                if result.stopped_reason is not None:
                    return result.stopped_reason, result
        finally:
            metrics["execution_time_s"] += world.sim_time - t0
        return None, result

    def _obstacle_at(self, ctx: EpisodeContext, hit: tuple[float, float] | None) -> Point | None:
        """Estimated centre of what a veto saw: the blocking return pushed back by the assumed radius."""
        if hit is None:
            return None
        depth = math.hypot(*hit) + self.cfg.obstacle_radius_m  # [m] from the robot to the assumed centre
        return ctx.world.robot.pose().point_at(math.atan2(hit[1], hit[0]), depth)

    def _obstacle_ahead(self, ctx: EpisodeContext, *, wide: bool = False) -> Point | None:
        """Estimated centre of what stopped the robot; None when the LiDAR sees nothing there.

        The closest return within ±15° ahead (±90° after an emergency stop), pushed back by the assumed
        obstacle radius.
        """
        # deferred: numpy (about 0.1 s) loads only when an obstacle is looked for
        import numpy as np

        scan = ctx.world.lidar.scan()
        pose = ctx.world.robot.pose()
        half = math.radians(90.0 if wide else 15.0)
        ranges = np.where(np.abs(scan.angles) <= half, scan.ranges, np.inf)
        i = int(np.argmin(ranges))
        r = float(ranges[i])  # [m]
        if not math.isfinite(r):
            return None
        depth = r + self.cfg.obstacle_radius_m  # [m] from the robot to the assumed centre
        return pose.point_at(float(scan.angles[i]), depth)

    @staticmethod
    def _count(metrics: dict[str, Any], plan: PlanResult) -> None:
        metrics["planning_time_s"] += plan.planning_time_s
        metrics["generations"] += len(plan.attempts)
        metrics["valid_generations"] += sum(a.valid for a in plan.attempts)

    @staticmethod
    def _leg_record(
        ctx: EpisodeContext,
        metrics: dict[str, Any],
        opened: _LegStart,
        replans: int,
        *,
        reached: bool,
        plan_failed: bool = False,
        collided: bool = False,
    ) -> dict[str, Any]:
        """One leg as source B's tables show it: what it cost and drove since it started where the last one ended."""
        spent = {k: metrics[k] - opened.counters[k] for k in LEG_COUNTERS}
        gens, valid = int(spent["generations"]), int(spent["valid_generations"])
        return {
            "command": opened.command,
            "target": opened.target_id,
            "reached": reached,
            "plan_failed": plan_failed,
            "start": [round(v, 4) for v in opened.pose.as_list()],
            "end": [round(v, 4) for v in ctx.world.robot.pose().as_list()],
            "planning_time_s": spent["planning_time_s"],
            "generations": gens,
            "valid_generations": valid,
            "wgsr": 100.0 * valid / gens if gens else None,
            "replans": replans,
            "execution_time_s": round(spent["execution_time_s"], 4),
            "path_length_m": round(spent["driven_m"], 4),
            "collision_events": int(spent["collision_events"]),
            "collided": collided,
        }

    @staticmethod
    def _leg_failed(
        ctx: EpisodeContext,
        metrics: dict[str, Any],
        opened: _LegStart,
        replans: int,
        reason: str,
        step: int,
        *,
        plan_failed: bool = False,
        collided: bool = False,
    ) -> EpisodeOutcome:
        """Record the unreached leg, then end the episode as failed."""
        record = WaypointPlanner._leg_record(
            ctx, metrics, opened, replans, reached=False, plan_failed=plan_failed, collided=collided
        )
        metrics["legs"].append(record)
        return WaypointPlanner._end(metrics, "failed", reason, step)

    @staticmethod
    def _end(metrics: dict[str, Any], outcome: str, reason: str, step: int) -> EpisodeOutcome:
        gens = metrics["generations"]
        metrics["wgsr"] = 100.0 * metrics["valid_generations"] / gens if gens else None
        exec_s = metrics["execution_time_s"]
        metrics["replanning_rate"] = metrics["replans"] / exec_s if exec_s > 0 else 0.0
        return EpisodeOutcome(outcome, reason, step, metrics)  # type: ignore[arg-type]
