"""Waypoint planner (source B): the model writes a JSON array of waypoints from the map facts.

Pipeline per target: ground the command in the scenario's object list (exact name first, the model picks
from the list otherwise) -> generate waypoints from corridor rectangles, robot pose and target pose ->
validate every point (inside a corridor with the margin, spacing, count, final point on the target,
segments clear of obstacles) and regenerate with the exact complaints, up to a bound -> follow them with
the P-controller (0.4 m/s, 2.0 rad/s, 0.1 m, 0.087 rad), stopping for obstacles closer than 0.5 m within
±15° ahead (emergency stop below 0.35 m) and replanning from the current pose, at most 5 times with a
5 s (sim) cooldown. Unlike the published code, out-of-bounds points are never dropped silently.

`generate_plan` needs no simulator: `llmnav plan` uses it directly.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from llmnav.chat import ChatRequest, ChatResult, Message
from llmnav.errors import InvalidActionError
from llmnav.geometry import Pose2D
from llmnav.guard.ask import CallContext, GuardedAnswer, ask_guarded
from llmnav.planners.base import DriveOptions, EpisodeContext, EpisodeOutcome, Planner, StepInfo

if TYPE_CHECKING:
    from llmnav.guard.parse import GuardResult
    from llmnav.guard.schemas import TargetChoice, WaypointList
    from llmnav.mapping.grid import OccupancyGrid
    from llmnav.scenario import LabelledObject, Scenario, Task, WaypointRules
    from llmnav.sim.motion import MotionResult

Point = tuple[float, float]
ModelCall = Callable[[ChatRequest, str], ChatResult]  # (request, purpose) -> reply


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


@dataclass
class Attempt:
    """One generation: the answer, its points and every complaint."""

    number: int
    latency_s: float
    points: list[Point]
    problems: list[str]
    outcome: str = "ok"  # guard outcome: "ok", "parse", "schema" (no usable array) or "bounds" (map rules)

    @property
    def valid(self) -> bool:
        """Whether the plan passed validation."""
        return not self.problems


@dataclass
class PlanResult:
    """The outcome of planning one target."""

    target_id: str
    target: Point
    attempts: list[Attempt] = field(default_factory=list)
    # [s] command -> waypoints received: the model's reported latency plus our own work (grounding
    # included when the caller adds it), so a replayed run reports the original's planning time
    planning_time_s: float = 0.0

    @property
    def waypoints(self) -> list[Point] | None:
        """The valid plan, if any attempt produced one."""
        return next((a.points for a in self.attempts if a.valid), None)

    @property
    def wgsr(self) -> float:
        """Waypoint generation success rate [%] = valid generations / attempts x 100."""
        return 100.0 * sum(a.valid for a in self.attempts) / len(self.attempts) if self.attempts else 0.0


@dataclass
class PlanningClock:
    """Times planning as the model's reported latency plus the wall time spent outside model calls.

    Wrap a `ModelCall` with it; `elapsed_s()` is then independent of how fast a replayed reply returns.
    """

    call: ModelCall
    started: float = field(default_factory=time.perf_counter)
    model_s: float = 0.0  # [s] latency the backend reported
    wall_in_calls_s: float = 0.0  # [s] wall time spent waiting for it

    def __call__(self, request: ChatRequest, purpose: str) -> ChatResult:
        """Forward the call and account for its time."""
        t0 = time.perf_counter()
        try:
            result = self.call(request, purpose)
        finally:
            self.wall_in_calls_s += time.perf_counter() - t0
        self.model_s += result.latency_s
        return result

    def elapsed_s(self) -> float:
        """Planning time since the clock started [s]."""
        return time.perf_counter() - self.started - self.wall_in_calls_s + self.model_s


# --- validation ------------------------------------------------------------------------------


def validate_waypoints(
    points: list[Point],
    start: Point,
    target: Point,
    scenario: Scenario,
    grid: OccupancyGrid | None,
    rules: WaypointRules,
    *,
    extra_obstacles: list[Point] | None = None,
    obstacle_radius_m: float = 0.35,
) -> list[str]:
    """Every problem of a plan, each naming the point and the rule; empty when the plan is valid."""
    problems: list[str] = []
    margin = rules.margin_m
    if len(points) > rules.max_waypoints:
        problems.append(f"{len(points)} waypoints; at most {rules.max_waypoints} are allowed here")
    previous = start
    for index, (x, y) in enumerate(points, start=1):
        name = f"waypoint {index} ({x:.2f}, {y:.2f})"
        if not any(c.contains(x, y, margin) for c in scenario.corridors):
            problems.append(f"{name} is outside every corridor with the {margin} m margin")
        gap = math.dist(previous, (x, y))
        if index < len(points) and gap < rules.spacing_m:
            problems.append(
                f"{name} is {gap:.2f} m from the previous point; keep at least {rules.spacing_m} m"
            )
        blocked = _segment_blocked(previous, (x, y), grid, extra_obstacles or [], obstacle_radius_m)
        if blocked is not None:
            (bx, by), seen = blocked
            seen_text = " seen on the way" if seen else ""
            problems.append(f"the segment to {name} crosses an obstacle near ({bx:.2f}, {by:.2f}){seen_text}")
        previous = (x, y)
    if points:
        miss = math.dist(points[-1], target)
        if miss > rules.target_tolerance_m:
            problems.append(
                f"the final waypoint is {miss:.2f} m from the target ({target[0]:.2f}, {target[1]:.2f}); "
                f"it must be within {rules.target_tolerance_m} m"
            )
    return problems


def _segment_blocked(
    a: Point, b: Point, grid: OccupancyGrid | None, extra: list[Point], radius: float
) -> tuple[Point, bool] | None:
    """Where segment a-b first meets an obstacle, if it does.

    (the first sample inside the inflated map grid, False), or (the centre of an obstacle seen on the
    way that the segment passes within `radius` [m] of, True).
    """
    steps = max(1, math.ceil(math.dist(a, b) / 0.05))
    for k in range(steps + 1):
        x, y = a[0] + (b[0] - a[0]) * k / steps, a[1] + (b[1] - a[1]) * k / steps
        # the first 0.15 m are exempt: a robot stopped close to a wall may start inside its inflation
        if grid is not None and not grid.is_free(x, y) and math.dist((x, y), a) > 0.15:
            return (x, y), False
        for obstacle in extra:
            if math.dist((x, y), obstacle) < radius:
                return obstacle, True
    return None


# --- grounding and generation ------------------------------------------------------------------


def ground_target(
    scenario: Scenario,
    task: Task,
    call: ModelCall,
    max_tries: int = 3,
    *,
    near: Point | None = None,
    tolerance_m: float = 0.05,
    step: int | None = None,
    on_event: Callable[..., None] | None = None,
) -> LabelledObject:
    """The object a command refers to: exact-name match first, else the model picks from the list.

    `near` (the final waypoint of a plan made already) settles an ambiguous command without a model call
    when exactly one candidate's goal point lies within `tolerance_m` [m] of it. The model's pick goes
    through `ask_guarded` (`max_tries` replies at most); `on_event` receives its `guard` events.
    """
    from llmnav.guard.schemas import response_schema, target_choice_model
    from llmnav.prompting import render
    from llmnav.tasks import named_objects

    if task.targets and len(task.targets) == 1 and task.targets[0].object:
        return scenario.object(task.targets[0].object)
    named = named_objects(scenario, task.text)
    if len(named) == 1:
        return named[0]
    candidates = named or list(scenario.objects)
    if near is not None:
        close = [o for o in candidates if math.dist(o.goal_point, near) <= tolerance_m]
        if len(close) == 1:
            return close[0]
    model = target_choice_model(tuple(o.id for o in candidates))
    listing = "\n".join(
        f"- {o.id}: {o.label} at ({o.goal_point[0]:.1f}, {o.goal_point[1]:.1f})" for o in candidates
    )
    messages = (
        Message("system", render("ground_system")),
        Message("user", render("ground_user", command=task.text, objects=listing)),
    )
    request = ChatRequest(messages, response_schema(model), 0.0, 64)
    answer: GuardedAnswer[TargetChoice] = ask_guarded(
        CallContext(call, on_event), request, model, None, max_tries - 1, step=step, purpose="ground"
    )
    if answer.value is None:
        raise InvalidActionError(f"the model named no listed object for '{task.text}' after {max_tries} tries")
    return scenario.object(answer.value.object_id)


def waypoint_schema(rules: WaypointRules) -> dict[str, Any]:
    """The answer's JSON Schema, with the environment's waypoint count as `maxItems`.

    A grammar-constrained model then cannot ramble on past it; the validator still checks the count.
    """
    from llmnav.guard.schemas import WaypointList, response_schema

    return {**response_schema(WaypointList), "maxItems": rules.max_waypoints}


def generate_plan(
    scenario: Scenario,
    target: LabelledObject,
    start: Pose2D,
    call: ModelCall,
    *,
    max_generations: int,
    grid: OccupancyGrid | None,
    temperature: float = 0.0,
    seed: int | None = None,
    seen_obstacles: list[Point] | None = None,
    obstacle_clearance_m: float = 0.555,
    on_attempt: Callable[[Attempt], None] | None = None,
    step: int | None = None,
    on_event: Callable[..., None] | None = None,
) -> PlanResult:
    """Ask for waypoints through `ask_guarded` until a plan validates or `max_generations` replies are spent.

    The map rules (`validate_waypoints`) are the guard's bounds; a plan breaking them is sent back with
    every broken rule listed. `seen_obstacles` are obstacle centres found on the way (replanning); every
    segment must keep `obstacle_clearance_m` [m] from them, and the prompt says so. `on_event` receives
    the guard's events (one `guard` event per reply).
    """
    from llmnav.guard.parse import correction_message, parse_answer
    from llmnav.guard.schemas import WaypointList
    from llmnav.prompting import render

    clock = PlanningClock(call)
    rules = scenario.waypoint_rules
    goal = target.goal_point
    corridors = "\n".join(
        f"- {c.id}: x from {c.x[0]} to {c.x[1]}, y from {c.y[0]} to {c.y[1]}" for c in scenario.corridors
    )
    junctions = [o for o in scenario.objects if "junction" in o.label.lower()]
    obstacles = "; ".join(f"({x:.2f}, {y:.2f})" for x, y in seen_obstacles or [])
    if obstacles:
        obstacles += f" (keep every segment at least {obstacle_clearance_m:.2f} m from each)"
    system = render(
        "waypoints_system",
        corridors=corridors or "- (no corridors published)",
        junctions="; ".join(f"{o.label} at ({o.center[0]}, {o.center[1]})" for o in junctions) or "none",
        robot_x=f"{start.x:.2f}",
        robot_y=f"{start.y:.2f}",
        robot_yaw_deg=f"{math.degrees(start.yaw):.0f}",
        target_name=target.label,
        target_x=f"{goal[0]:.2f}",
        target_y=f"{goal[1]:.2f}",
        margin=rules.margin_m,
        spacing=rules.spacing_m,
        tolerance=rules.target_tolerance_m,
        max_waypoints=rules.max_waypoints,
        obstacles=obstacles or "none",
    )
    user = render("waypoints_user", target_name=target.label, max_waypoints=rules.max_waypoints)
    schema = waypoint_schema(rules)
    request = ChatRequest((Message("system", system), Message("user", user)), schema, temperature, 512, seed)
    plan = PlanResult(target.id, goal)
    rules_check = PlanRules(scenario, (start.x, start.y), goal, grid, seen_obstacles or [], obstacle_clearance_m)

    def record(number: int, text: str, result: GuardResult[WaypointList], latency_s: float) -> None:
        if result.outcome in ("parse", "schema"):
            attempt = Attempt(number, latency_s, [], [f"{result.outcome}: {result.error}"], result.outcome)
        else:  # ok, or bounds: the plan was read, the map rules judged it
            read: GuardResult[WaypointList] = parse_answer(text, WaypointList)
            points = read.value.points if read.value is not None else []
            problems = rules_check.problems(points) if result.outcome == "bounds" else []
            attempt = Attempt(number, latency_s, points, problems, result.outcome)
        plan.attempts.append(attempt)
        if on_attempt is not None:
            on_attempt(attempt)

    def feedback(result: GuardResult[WaypointList]) -> str:
        if result.outcome == "bounds":
            return render("waypoints_feedback", problems="\n".join(f"- {p}" for p in (result.error or "").split("\n")))
        return correction_message(result, schema)

    ask_guarded(
        CallContext(clock, on_event),
        request,
        WaypointList,
        rules_check,
        max_generations - 1,
        step=step,
        purpose="waypoints",
        feedback=feedback,
        on_reply=record,
    )
    plan.planning_time_s = clock.elapsed_s()
    return plan


@dataclass(frozen=True)
class PlanRules:
    """The map rules as guard bounds: a plan read from the answer must satisfy `validate_waypoints`."""

    scenario: Scenario
    start: Point
    target: Point
    grid: OccupancyGrid | None
    seen_obstacles: list[Point]
    clearance_m: float

    def problems(self, points: list[Point]) -> list[str]:
        """Every broken rule, one sentence each."""
        return validate_waypoints(
            points,
            self.start,
            self.target,
            self.scenario,
            self.grid,
            self.scenario.waypoint_rules,
            extra_obstacles=self.seen_obstacles,
            obstacle_radius_m=self.clearance_m,
        )

    def check(self, value: Any) -> str | None:
        """The broken rules, one per line, or None."""
        found = self.problems([(float(x), float(y)) for x, y in value.points])
        return "\n".join(found) or None


def map_to_odom(point: Point, start_map: Pose2D, start_odom: Pose2D) -> Point:
    """A map-frame point in the odometry frame: rotate by the frame offset, then translate."""
    dtheta = start_odom.yaw - start_map.yaw
    dx, dy = point[0] - start_map.x, point[1] - start_map.y
    c, s = math.cos(dtheta), math.sin(dtheta)
    return (start_odom.x + c * dx - s * dy, start_odom.y + s * dx + c * dy)


# --- the planner ---------------------------------------------------------------------------------


class WaypointPlanner(Planner):
    """Source B on the simulator; several targets in sequence with repeated `--task`."""

    name = "waypoints"
    needs_backend = True
    options = frozenset({"temperature", "max_generations", "max_replans", "replan_cooldown_s", "preset_waypoints"})

    def __init__(self, config: WaypointConfig | None = None) -> None:
        self.cfg = config or WaypointConfig()

    @staticmethod
    def templates(options: DriveOptions) -> list[str]:
        """Prompt templates this planner renders (their hashes go into the run config)."""
        return ["ground_system", "ground_user", "waypoints_system", "waypoints_user", "waypoints_feedback"]

    def run(self, ctx: EpisodeContext) -> EpisodeOutcome:
        """Ground, plan, validate, execute, replan — per leg of the command sequence."""
        from llmnav.mapping.grid import build_grid
        from llmnav.observe import call_model
        from llmnav.tasks import sequence_legs

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
            "legs": [],
        }

        def call(request: ChatRequest, purpose: str) -> ChatResult:
            return call_model(ctx, request, purpose=purpose, step=step)

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
                scenario, leg, clock, near=near, tolerance_m=rules.target_tolerance_m, step=step, on_event=ctx.event
            )
            grounding_s = clock.elapsed_s()  # [s] counted in this leg's first planning time
            note("grounding", command=leg.text, target=target.id)
            seen: list[Point] = []
            replans = 0
            while True:
                start = world.robot.pose()
                if preset:  # `llmnav plan --execute`: the plan was made already; it is validated again
                    problems = validate_waypoints(
                        preset, (start.x, start.y), target.goal_point, scenario, grid, rules
                    )
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
                    metrics["legs"].append({"target": target.id, "reached": False, "replans": replans})
                    return self._end(
                        metrics,
                        "failed",
                        f"no valid waypoints for {target.label} after {len(plan.attempts)} generations",
                        step,
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
                    metrics["legs"].append({"target": target.id, "reached": False, "replans": replans})
                    return self._end(metrics, "failed", "collided while following waypoints", step)
                obstacle: Point | None = None
                if stop in ("obstacle", "emergency"):  # a LiDAR reading below the stop distance
                    metrics["collision_events"] += 1
                    obstacle = self._obstacle_ahead(ctx, wide=stop == "emergency")
                elif stop == "vetoed":  # the motion layer refused the next segment: something is on it
                    metrics["vetoed_segments"] += 1
                    obstacle = self._obstacle_at(ctx, last.veto_hit if last is not None else None)
                if obstacle is not None:
                    seen.append(obstacle)
                if replans >= opts.max_replans:
                    metrics["legs"].append({"target": target.id, "reached": False, "replans": replans})
                    return self._end(
                        metrics,
                        "failed",
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
            metrics["legs"].append({"target": target.id, "reached": True, "replans": replans})
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

        Every segment goes through the guarded motion layer, which vetoes it before the robot moves when
        the LiDAR sees something on it (the map-based validation cannot know what the map lacks).
        """
        world, cfg = ctx.world, self.cfg
        start_odom = world.robot.odom()
        t0 = world.sim_time
        result: MotionResult | None = None
        try:
            for index, point in enumerate(waypoints, start=1):
                before = world.robot.pose()
                x, y = map_to_odom(point, start_map, start_odom)
                result = world.motion.go_to(
                    x,
                    y,
                    tol_m=cfg.reach_tol_m,
                    ang_tol=cfg.angle_tol_rad,
                    v_max=cfg.linear_speed,
                    w_max=cfg.angular_speed,
                    obstacle_stop_m=cfg.critical_m,
                    emergency_stop_m=cfg.emergency_m,
                )
                ctx.log.sim_time = world.sim_time
                ctx.log.event(
                    "action",
                    step=step,
                    command="WAYPOINT",
                    parameters=[round(point[0], 3), round(point[1], 3)],
                    index=index,
                    pose_before=before.as_list(),
                    pose_after=result.end.as_list(),
                    duration_s=round(result.duration_s, 3),
                    collided=result.collided,
                    collision_with=result.collision_with,
                    stopped_reason=result.stopped_reason,
                    **({"veto": result.veto} if result.veto is not None else {}),
                )
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
        pose = ctx.world.robot.pose()
        heading = pose.yaw + math.atan2(hit[1], hit[0])
        depth = math.hypot(*hit) + self.cfg.obstacle_radius_m  # [m] from the robot to the assumed centre
        return (pose.x + depth * math.cos(heading), pose.y + depth * math.sin(heading))

    def _obstacle_ahead(self, ctx: EpisodeContext, *, wide: bool = False) -> Point | None:
        """Estimated centre of what stopped the robot; None when the LiDAR sees nothing there.

        The closest return within ±15° ahead (±90° after an emergency stop), pushed back by the assumed
        obstacle radius.
        """
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
        heading = pose.yaw + float(scan.angles[i])
        return (pose.x + depth * math.cos(heading), pose.y + depth * math.sin(heading))

    @staticmethod
    def _count(metrics: dict[str, Any], plan: PlanResult) -> None:
        metrics["planning_time_s"] += plan.planning_time_s
        metrics["generations"] += len(plan.attempts)
        metrics["valid_generations"] += sum(a.valid for a in plan.attempts)

    @staticmethod
    def _end(metrics: dict[str, Any], outcome: str, reason: str, step: int) -> EpisodeOutcome:
        gens = metrics["generations"]
        metrics["wgsr"] = 100.0 * metrics["valid_generations"] / gens if gens else None
        exec_s = metrics["execution_time_s"]
        metrics["replanning_rate"] = metrics["replans"] / exec_s if exec_s > 0 else 0.0
        return EpisodeOutcome(outcome, reason, step, metrics)  # type: ignore[arg-type]


def plan_summary(plan: PlanResult) -> dict[str, Any]:
    """JSON-able summary of a plan (for `llmnav plan --json`)."""
    return {
        "target": plan.target_id,
        "target_point": list(plan.target),
        "waypoints": plan.waypoints,
        "planning_time_s": round(plan.planning_time_s, 3),
        "wgsr": plan.wgsr,
        "attempts": [
            {"number": a.number, "points": a.points, "valid": a.valid, "problems": a.problems}
            for a in plan.attempts
        ],
    }


def plan_json(plan: PlanResult) -> str:
    """`plan_summary` as JSON text."""
    return json.dumps(plan_summary(plan), indent=2)
