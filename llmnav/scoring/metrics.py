"""Episode metrics: the stepwise source's score, success, path length and the per-run summary.

Every number in `summary.json` comes from `summarize_run`, which reads only the run log (the event
vocabulary of `llmnav.runs.runlog`) and the scenario. The runner calls it when an episode ends; `llmnav score`
calls it on runs that were cut short. Definitions (see docs/metrics.md):

- score S = distance_score(d) * heading_score(alpha) at the final pose, for the best acceptable target
  (the one with the largest S);
- distance_score(d) = 1 if d <= 2.5 m else 1.5 ** -(d - 2.5);
- heading_score(alpha) = (pi - alpha) / pi, alpha in [0, pi] the angle between heading and the direction
  to the target;
- success = the episode completed (the model said COMPLETE or the planner reached its own end) with
  d <= 2.5 m; rotate tasks: completed with a total rotation of at least 360 deg minus 10 deg (score 1 when
  the rotation holds, else 0); explore tasks: score N.A. (None), success = completed.
- oracle success = the trajectory came within the success radius of an acceptable target at any time;
- SPL = S * l / max(p, l) and Soft-SPL = progress * l / max(p, l), with l the shortest collision-free path
  from the start to within the success radius of the nearest acceptable target (the oracle's grid), p the
  true path length and progress = clip(1 - d_T / d_0, 0, 1) over the same geodesic distance;
- failure_cause: one cause per failed run (`llmnav.scoring.failures`).
The success radius is 2.5 m unless `llmnav score --success-radius` asks for another.
"""

from __future__ import annotations

import functools
import math
import re
import statistics
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from llmnav.backends.prices import load_prices, run_cost
from llmnav.core.geometry import Point, Pose2D, logged_pose, path_length, wrap_angle
from llmnav.scoring.failures import failure_cause

if TYPE_CHECKING:
    from llmnav.backends.prices import PriceTable
    from llmnav.planners.base import EpisodeOutcome
    from llmnav.runs.runlog import RunRecord
    from llmnav.world.scenario import Scenario

SUCCESS_RADIUS_M = 2.5  # [m] d at or below which distance_score is 1 and a completed run succeeds
DISTANCE_DECAY_BASE = 1.5  # distance_score = base ** -(d - radius) beyond the radius
ROTATION_TOLERANCE_RAD = math.radians(10.0)  # [rad] slack on the 360 deg task
FULL_TURN_RAD = 2.0 * math.pi  # [rad]
GUARD_JSON_OUTCOMES = frozenset({"parse", "schema", "bounds"})
GUARD_VETO_OUTCOME = "veto"
RUN_KEYS: tuple[str, ...] = ("planner", "backend")  # what every run's condition starts with


@functools.cache
def condition_keys() -> tuple[str, ...]:
    """The keys of a run's condition: what `score` groups by and `ablate` varies.

    Planner and backend, then each registered planner's declared `condition_keys`, planners by name, each
    key once. Every run's condition holds them all (None where its planner has no such option), so runs of
    different planners sit in one table. A broken planner plug-in is left out (`usable_planner_names`).
    """
    # deferred: the planner registry brings pydantic (about 0.1 s), only once a run's condition is built
    from llmnav.planners.base import planner_class, usable_planner_names

    keys = list(RUN_KEYS)
    for name in usable_planner_names():
        keys += [k for k in planner_class(name).condition_keys if k not in keys]
    return tuple(keys)


def distance_score(distance_m: float) -> float:
    """1 within 2.5 m of the target, then decaying by a factor 1.5 per extra metre."""
    if distance_m <= SUCCESS_RADIUS_M:
        return 1.0
    return float(DISTANCE_DECAY_BASE ** -(distance_m - SUCCESS_RADIUS_M))


def heading_score(alpha_rad: float) -> float:
    """(pi - alpha) / pi for alpha in [0, pi]: 1 facing the target, 0 facing away."""
    alpha = min(abs(alpha_rad), math.pi)
    return (math.pi - alpha) / math.pi


@dataclass(frozen=True)
class TargetScore:
    """The score of a pose with respect to one target point."""

    score: float
    distance_m: float  # [m]
    heading_error_rad: float  # [rad] in [0, pi]
    index: int  # which acceptable target


def score_pose(pose: Pose2D, target: Point, index: int = 0, face: Point | None = None) -> TargetScore:
    """S = distance_score * heading_score of a pose against one target.

    d is measured to the target's goal point; alpha to `face`, the object itself when its goal point is a
    separate stand point (a room plate on a wall), else to the goal point too.
    """
    distance = pose.distance_to(*target)
    look = face if face is not None else target
    # At the target itself the direction is undefined: count that as facing it.
    alpha = abs(pose.bearing_to(*look)) if pose.distance_to(*look) > 1e-9 else 0.0
    return TargetScore(distance_score(distance) * heading_score(alpha), distance, alpha, index)


def best_target(
    pose: Pose2D, targets: Sequence[Point], faces: Sequence[Point | None] | None = None
) -> TargetScore | None:
    """The acceptable target with the largest S (ties: the nearer one); None without targets."""
    faces = faces if faces is not None else [None] * len(targets)
    scored = [score_pose(pose, t, i, f) for i, (t, f) in enumerate(zip(targets, faces, strict=True))]
    if not scored:
        return None
    return max(scored, key=lambda s: (s.score, -s.distance_m))


def total_rotation(poses: Iterable[Sequence[float]]) -> float:
    """The largest net turn [rad] reached in one direction along the trajectory.

    Yaw is unwrapped sample to sample, so samples must be closer than pi apart in yaw (motion logs
    samples while turning). Net, not absolute: turning 180 deg left then back right is no full turn.
    """
    cumulative = 0.0
    largest = 0.0
    previous: float | None = None
    for pose in poses:
        yaw = float(pose[2])
        if previous is not None:
            cumulative += wrap_angle(yaw - previous)
            largest = max(largest, abs(cumulative))
        previous = yaw
    return largest


def rotation_done(rotation_rad: float) -> bool:
    """Whether a net rotation counts as the full 360 deg turn (within the tolerance)."""
    return rotation_rad >= FULL_TURN_RAD - ROTATION_TOLERANCE_RAD


# --- reading the configuration line ------------------------------------------------------------


def _as_pose(value: Any) -> Pose2D | None:
    """A pose from the forms logs use: [x, y, yaw], {x, y, yaw} or {x, y, yaw_deg}."""
    try:
        if isinstance(value, dict):
            yaw = value["yaw"] if "yaw" in value else math.radians(float(value.get("yaw_deg", 0.0)))
            return Pose2D(float(value["x"]), float(value["y"]), float(yaw))
        pose = logged_pose(value)
        if pose is not None:
            return Pose2D(pose[0], pose[1], pose[2] if len(pose) > 2 else 0.0)
    except (KeyError, TypeError, ValueError):
        return None
    return None


def _target_point(target: Any, scenario: Scenario | None) -> Point | None:
    """One logged target ({object}, {point}, [x, y] or {x, y}) as a goal point."""
    if isinstance(target, (list, tuple)) and len(target) >= 2:
        return (float(target[0]), float(target[1]))
    if not isinstance(target, dict):
        return None
    if target.get("point") is not None:
        return (float(target["point"][0]), float(target["point"][1]))
    if "x" in target and "y" in target:
        return (float(target["x"]), float(target["y"]))
    if target.get("object") is not None and scenario is not None:
        try:
            return scenario.object(str(target["object"])).goal_point
        except KeyError:
            return None
    return None


def _face_point(target: Any, scenario: Scenario | None) -> Point | None:
    """The object a target names, when its goal point is a separate stand point (else None).

    Stand points exist in corridor worlds (source B): the robot stops on the point in front of a plate and
    faces the plate. Elsewhere the goal point is simply where distances are measured to.
    """
    if not isinstance(target, dict) or target.get("object") is None or scenario is None or not scenario.corridors:
        return None
    try:
        obj = scenario.object(str(target["object"]))
    except KeyError:
        return None
    return obj.center if obj.goal is not None else None


def _task_info(
    config: dict[str, Any], scenario: Scenario | None
) -> tuple[dict[str, Any], list[Point], list[Point | None]]:
    """The task as logged (falling back to the scenario's task of that id) and its target points."""
    logged = config.get("task")
    task: dict[str, Any] = dict(logged) if isinstance(logged, dict) else {"text": logged}
    known = None
    if scenario is not None and task.get("id"):
        try:
            known = scenario.task(str(task["id"]))
        except KeyError:
            known = None
    if known is not None:
        task.setdefault("text", known.text)
        task.setdefault("kind", known.kind)
        task.setdefault("difficulty", known.difficulty)
        if not task.get("targets"):
            task["targets"] = [t.model_dump() for t in known.targets]
    pairs = [(_target_point(t, scenario), _face_point(t, scenario)) for t in task.get("targets") or []]
    points = [p for p, _ in pairs if p is not None]
    faces = [f for p, f in pairs if p is not None]
    task.setdefault("kind", "target" if points else "explore")
    return task, points, faces


def condition_of(config: dict[str, Any], events: Sequence[Mapping[str, Any]] = ()) -> dict[str, Any]:
    """The condition of a run: its planner, backend and the options an ablation varies.

    What the run actually did wins over what was asked: an event carrying `condition` (a fallback from
    `decide=auto` to generation, an assist that died) replaces those keys' values, so tables never pool
    such a run with the condition it was asked for (`decide=generate (fallback)`, `assist=llm (failed)`).
    """
    options = config.get("options") or {}
    condition: dict[str, Any] = {}
    for key in condition_keys():
        if key == "backend":
            value = config.get("backend", options.get("backend"))
        elif key == "planner":
            value = config.get("planner", options.get("planner"))
        else:
            value = options.get(key)
        if isinstance(value, (list, tuple)):  # sensing: ("lidar", "image") -> "lidar+image", as on the CLI
            value = "+".join(str(v) for v in value)
        condition[key] = value
    for event in events:
        changed = event.get("condition")
        if isinstance(changed, dict):
            condition.update({k: str(v) for k, v in changed.items() if k in condition and isinstance(v, str)})
    return condition


def _mean(values: Sequence[float]) -> float | None:
    return sum(values) / len(values) if values else None


def _last_time(events: Sequence[dict[str, Any]], key: str) -> float | None:
    for event in reversed(events):
        value = event.get(key)
        if isinstance(value, (int, float)):
            return float(value)
    return None


def _rounded(value: float | None, digits: int = 4) -> float | None:
    return None if value is None else round(value, digits)


def _added_obstacles(config: dict[str, Any]) -> list[Point]:
    """The centres of the boxes `--obstacle` dropped (logged in the options), for the scoring grid."""
    added = (config.get("options") or {}).get("obstacles") or []
    try:
        return [(float(o[0]), float(o[1])) for o in added]
    except (TypeError, ValueError, IndexError):
        return []


# --- the summary -------------------------------------------------------------------------------


def crashed(reason: object) -> bool:
    """Whether an end reason says llmnav itself crashed or was interrupted (the runner's "crash: ..." reasons)."""
    return isinstance(reason, str) and (reason.startswith("crash:") or reason == "interrupted")


def aborted_without_result(summary: dict[str, Any]) -> bool:
    """Whether a run ended with nothing to score: its backend or server failed, or llmnav crashed under it.

    Such runs carry no score, are in no mean and are tabled apart with their cause (`llmnav score`).
    """
    return aborted_by_infrastructure(summary) or (
        summary.get("outcome") == "aborted" and crashed(summary.get("reason"))
    )


def aborted_by_infrastructure(summary: dict[str, Any]) -> bool:
    """Whether a run ended because the backend or its server failed (no answer came): not the model's result.

    Such runs are never in a model's means (`llmnav score` lists them apart) and carry no score.
    """
    metrics = summary.get("planner_metrics")
    return summary.get("outcome") == "aborted" and isinstance(metrics, dict) and metrics.get("failure") == "backend"


# "collided with X", "collision with X"; not "no collision-free path"
_COLLISION_REASON = re.compile(r"\bcolli(?:ded|sion)\b(?!-free)(?: with (?P<what>.+))?", re.I)


def count_collisions(
    actions: Sequence[Mapping[str, Any]], planner_metrics: Mapping[str, Any], reason: str
) -> tuple[int, list[str]]:
    """The episode's collision events and what was hit (distinct names, in order).

    Counted: `action` events with `collided: true`; the planner's own count when it is larger (a planner that
    keeps driving after a contact); and one for an episode whose end reason reports a contact no `action`
    event recorded (a velocity controller logs ticks, not actions).
    """
    count = sum(1 for a in actions if a.get("collided"))
    hit = [str(a.get("collision_with") or "an obstacle") for a in actions if a.get("collided")]
    own = planner_metrics.get("collisions")
    if isinstance(own, int) and not isinstance(own, bool):
        count = max(count, own)
    said = _COLLISION_REASON.search(reason)
    if count == 0 and said is not None:
        count = 1
        hit.append((said.group("what") or "an obstacle").strip())
    return count, list(dict.fromkeys(hit))


def _progress(d_start: float | None, d_end: float | None) -> float | None:
    """Soft success: 1 - d_T / d_0 clipped to [0, 1] (None when either is unknown or d_0 is 0)."""
    if d_start is None or d_end is None or d_start <= 0.0:
        return None
    return min(1.0, max(0.0, 1.0 - d_end / d_start))


def _weighted(value: float | None, shortest_m: float | None, travelled_m: float) -> float | None:
    """The SPL weighting value * l / max(p, l)'s path weighting (None without l or when l is 0: no path to weigh)."""
    if value is None or shortest_m is None or shortest_m <= 0.0:
        return None
    return value * shortest_m / max(travelled_m, shortest_m)


def reach_metrics(
    *,
    targets: Sequence[Point],
    best: TargetScore | None,
    completed: bool,
    poses: Sequence[Sequence[float]],
    start: Pose2D | None,
    final: Pose2D | None,
    scenario: Scenario | None,
    obstacles: Sequence[Point],
    radius_m: float = SUCCESS_RADIUS_M,
) -> dict[str, Any]:
    """Success at `radius_m` [m], oracle success, and SPL and Soft-SPL for a target task.

    - success: completed and the best target (`best_target`) within the radius of the final pose;
    - oracle_success: some trajectory sample came within the radius of an acceptable target;
    - shortest_path_m (l): `llmnav.mapping.targets.goal_distance` from the start (the oracle's true grid,
      inflated by the robot radius, added obstacles included): the shortest collision-free path to within
      the radius of the nearest acceptable target; goal_distance_m (d_T): the same from the final pose;
    - spl = S * l / max(p, l) (Anderson et al. 2018), p the true path length;
    - soft_spl = progress * l / max(p, l), progress = clip(1 - d_T / d_0, 0, 1) with d_0 = l (Habitat).
    Geodesic values need the scenario; without it (or with l = 0: the start already within the radius) the
    SPLs are None.
    """
    travelled = path_length(poses)
    closest = min((math.hypot(p[0] - x, p[1] - y) for p in poses for x, y in targets), default=None)
    shortest = final_distance = None
    if scenario is not None and targets:
        # deferred: the oracle's map brings numpy (about 0.1 s), only when a scenario is given
        from llmnav.mapping.targets import goal_distance, with_added_obstacles

        known = with_added_obstacles(scenario, obstacles)
        if start is not None:
            shortest = goal_distance(known, targets, (start.x, start.y), radius_m)
        if final is not None:
            final_distance = goal_distance(known, targets, (final.x, final.y), radius_m)
    success = completed and best is not None and best.distance_m <= radius_m
    return {
        "success": success,
        "success_radius_m": radius_m,
        "oracle_success": closest is not None and closest <= radius_m,
        "closest_approach_m": _rounded(closest),
        "shortest_path_m": _rounded(shortest),
        "goal_distance_m": _rounded(final_distance),
        "spl": _rounded(_weighted(1.0 if success else 0.0, shortest, travelled)),
        "soft_spl": _rounded(_weighted(_progress(shortest, final_distance), shortest, travelled)),
    }


NO_REACH: dict[str, Any] = {  # tasks without a target (rotate, explore) and runs nothing of the model's ended
    "oracle_success": None,
    "closest_approach_m": None,
    "shortest_path_m": None,
    "goal_distance_m": None,
    "spl": None,
    "soft_spl": None,
}
# What `llmnav score` recomputes from the log at another success radius (and fills in for older summaries).
RESCORED_KEYS: tuple[str, ...] = ("success", "success_radius_m", *NO_REACH, "failure_cause")


def summarize_run(
    record: RunRecord,
    scenario: Scenario | None,
    outcome: EpisodeOutcome | None = None,
    *,
    success_radius_m: float = SUCCESS_RADIUS_M,
    prices: PriceTable | None = None,
) -> dict[str, Any]:
    """Every metric of one episode, from its run log (complete or cut short) and its scenario.

    `outcome` is the planner's return value when the runner calls this at the end of an episode;
    otherwise the `end` event is used, and a run without one counts as aborted ("cut short").
    `scenario` may be None when it cannot be loaded: targets logged as points still score.
    `success_radius_m` [m]: the radius success is judged at (`llmnav score --success-radius`); the score's
    distance term keeps its own 2.5 m. `prices`: the table `cost_usd` is computed with (default: `$LLMNAV_PRICES`,
    else the bundled one; see `llmnav.backends.prices`).
    """
    config = record.config
    events = record.events
    task, targets, faces = _task_info(config, scenario)
    end_events = record.of_type("end")
    end = end_events[-1] if end_events else None

    result: str
    if outcome is not None:
        result, reason, planner_metrics = outcome.outcome, outcome.reason, dict(outcome.metrics)
        iterations: int | None = outcome.iterations
    elif end is not None:
        result = str(end.get("outcome", "aborted"))
        reason = str(end.get("reason", ""))
        planner_metrics = dict(end.get("metrics") or {})
        iterations = end.get("iterations") if isinstance(end.get("iterations"), int) else None
    else:
        result, reason, planner_metrics, iterations = "aborted", "cut short: no end event", {}, None

    actions = record.of_type("action")
    if iterations is None:  # one reasoning-action cycle per distinct step
        iterations = len({a.get("step", i) for i, a in enumerate(actions)})

    latencies = [
        float(call["reply"]["latency_s"])
        for call in record.of_type("llm_call")
        if isinstance(call.get("reply"), dict) and isinstance(call["reply"].get("latency_s"), (int, float))
    ]
    guards = [str(g.get("outcome")) for g in record.of_type("guard")]

    poses = record.poses()
    final = _as_pose(poses[-1]) if poses else None
    if final is None and actions:
        final = _as_pose(actions[-1].get("pose_after"))
    if final is None:
        final = _as_pose(config.get("start_pose"))

    completed = result == "completed"
    kind = task.get("kind")
    rotation = total_rotation(poses)
    best = best_target(final, targets, faces) if final is not None and kind == "target" else None
    reach: dict[str, Any] = {**NO_REACH, "success_radius_m": success_radius_m}
    score: float | None
    if kind == "rotate":
        score = 1.0 if rotation_done(rotation) else 0.0
        success = completed and rotation_done(rotation)
    elif kind == "explore":
        score, success = None, completed
    elif best is not None:
        score = best.score
        reach = reach_metrics(
            targets=targets,
            best=best,
            completed=completed,
            poses=poses,
            start=_as_pose(config.get("start_pose")),
            final=final,
            scenario=scenario,
            obstacles=_added_obstacles(config),
            radius_m=success_radius_m,
        )
        success = reach["success"]
    else:  # a target task whose targets cannot be resolved: nothing to score against
        score, success = None, False

    if result == "aborted" and (planner_metrics.get("failure") == "backend" or crashed(reason)):
        # the server failed, or llmnav crashed, not the model: nothing of the model's to score
        score, success = None, False
        reach = {**NO_REACH, "success_radius_m": success_radius_m}

    collisions, collided_with = count_collisions(actions, planner_metrics, reason)

    summary: dict[str, Any] = {
        "outcome": result,
        "reason": reason,
        "cut_short": end is None and outcome is None,
        "scenario": config.get("scenario"),
        "task_id": task.get("id"),
        "task_text": task.get("text"),
        "task_kind": kind,
        "difficulty": task.get("difficulty"),
        "planner": config.get("planner", (config.get("options") or {}).get("planner")),
        "backend": config.get("backend"),
        "start_pose_index": config.get("start_pose_index"),
        "seed": config.get("seed"),
        "condition": condition_of(config, record.events),
        "iterations": iterations,
        "latency_s_mean": _rounded(_mean(latencies)),
        "llm_calls": len(record.of_type("llm_call")),
        "new_prompt_tokens_median": new_prompt_tokens_median(record.of_type("llm_call")),
        # cache_hits, tokens, cost_usd (None: unknown) and cost_note
        **run_cost(config, record.of_type("llm_call"), prices or load_prices()),
        "json_errors": sum(1 for g in guards if g in GUARD_JSON_OUTCOMES),
        "safety_vetoes": sum(1 for g in guards if g == GUARD_VETO_OUTCOME),
        "final_pose": final.as_list() if final is not None else None,
        "distance_m": _rounded(best.distance_m) if best is not None else None,
        "heading_error_rad": _rounded(best.heading_error_rad) if best is not None else None,
        "target_index": best.index if best is not None else None,
        "score": _rounded(score),
        "success": bool(success),
        **{k: v for k, v in reach.items() if k != "success"},
        "path_length_m": round(path_length(poses), 4),
        "rotation_total_rad": round(rotation, 4),
        "collisions": collisions,
        "collided_with": collided_with,
        "pose_error_m": pose_error(events),
        "sim_time_s": _rounded(_last_time(events, "t_sim")),
        "wall_time_s": _rounded(_last_time(events, "t_wall")),
        "planner_metrics": planner_metrics,
    }
    summary["failure_cause"] = failure_cause(summary, actions[-1] if actions else None)
    return summary


def pose_error(events: Sequence[dict[str, Any]]) -> dict[str, float] | None:
    """How far [m] the planner's believed pose was from the truth: {"final": ..., "max": ...}, or None.

    Each `localize` event (the planner's estimate) is compared with the last true `pose` sample logged
    before it; "final" is the last such comparison. For scoring only: the planner never sees it.
    """
    truth: list[float] | None = None
    errors: list[float] = []
    for event in events:
        if event.get("type") == "pose":
            truth = logged_pose(event.get("pose")) or truth
        elif event.get("type") == "localize" and truth is not None:
            belief = logged_pose(event.get("pose"))
            if belief is not None:
                errors.append(math.hypot(belief[0] - truth[0], belief[1] - truth[1]))
    if not errors:
        return None
    return {"final": round(errors[-1], 4), "max": round(max(errors), 4)}


def new_prompt_tokens_median(calls: Sequence[dict[str, Any]]) -> float | None:
    """Median of the prompt tokens the model read afresh per call, after the episode's first call.

    The first call pays for the fixed system prompt once; the budget that matters is every call after it.
    None when the backend does not report them (or there is at most one call).
    """
    counts = [c["new_prompt_tokens"] for c in calls[1:] if isinstance(c.get("new_prompt_tokens"), int)]
    return float(statistics.median(counts)) if counts else None
