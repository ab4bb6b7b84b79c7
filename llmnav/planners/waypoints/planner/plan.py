"""Generating a waypoint plan (source B, docs/sources.md B); needs no simulator (`llmnav plan` uses it).

The prompt from the map facts, the guarded ask with the map rules as bounds, and the record of every attempt.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from llmnav.core.chat import ChatRequest, ChatResult, Message
from llmnav.core.geometry import Point
from llmnav.guard.ask import CallContext, ask_guarded
from llmnav.guard.parse import correction_message, parse_answer
from llmnav.guard.schemas import response_schema
from llmnav.planners.prompting import render
from llmnav.planners.waypoints.planner.answers import WaypointList
from llmnav.planners.waypoints.planner.validate import PlanRules

if TYPE_CHECKING:
    from llmnav.core.geometry import Pose2D
    from llmnav.guard.parse import GuardResult
    from llmnav.mapping.grid import OccupancyGrid
    from llmnav.world.scenario import LabelledObject, Scenario, WaypointRules

ModelCall = Callable[[ChatRequest, str], ChatResult]  # (request, purpose) -> reply


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


def waypoint_schema(rules: WaypointRules) -> dict[str, Any]:
    """The answer's JSON Schema, with the environment's waypoint count as `maxItems`.

    A grammar-constrained model then cannot ramble on past it; the validator still checks the count.
    """
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


def plan_summary(plan: PlanResult) -> dict[str, Any]:
    """JSON-able summary of a plan (for `llmnav plan --json`)."""
    return {
        "target": plan.target_id,
        "target_point": list(plan.target),
        "waypoints": plan.waypoints,
        "planning_time_s": round(plan.planning_time_s, 3),
        "wgsr": plan.wgsr,
        "attempts": [
            {"number": a.number, "points": a.points, "valid": a.valid, "problems": a.problems} for a in plan.attempts
        ],
    }


def plan_json(plan: PlanResult) -> str:
    """`plan_summary` as JSON text."""
    return json.dumps(plan_summary(plan), indent=2)
