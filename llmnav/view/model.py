"""What a run page shows, as plain data: one run folder read back and arranged by decision.

`build_run_view` reads the folder once with the run-log reader (`llmnav.runs.runlog.read_run`), takes the
summary from that record the way `llmnav score` does (`llmnav.runs.folders.run_from_record`: summary.json,
or recomputed for a run cut short), and groups the events into decisions:

- most planners: one decision per logged `step` value, named by the planner's `decision_noun` ("Step 3";
  a waypoint decision is one leg: its grounding, every generation attempt with its verdict, the replans);
- a planner that declares `velocity_view` (it commands velocities every tick): one decision per model
  suggestion (its verdict: accepted, stale, bounds, parse), else one per state change, and its command
  profile.

What a planner declares (`llmnav.core.declarations`) is looked up through the planner registry; for a run whose
planner is not installed here, the log's own content stands in (velocity commands or suggestions, model
calls made at decisions).

Everything here tolerates missing fields and missing events: a killed run shows what it logged and each
decision says what it lacks. Nothing here renders HTML (see `llmnav.view.page`).
"""

from __future__ import annotations

import bisect
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from llmnav.core.declarations import Declarations, declarations_of
from llmnav.core.geometry import logged_pose
from llmnav.errors import BadInputError
from llmnav.reporting.trajectory import oracle_points
from llmnav.reporting.velocity import well_formed_cmd
from llmnav.runs.runlog import IMAGES_DIR, RunRecord, read_run
from llmnav.scoring.metrics import SUCCESS_RADIUS_M
from llmnav.sensing.relevance import CONTENT_FREE_TASK

if TYPE_CHECKING:
    from llmnav.world.scenario import Scenario, Task

REASONING_CHARS = 160  # one line of reasoning in captions and the step list

_SECTOR_LINE = re.compile(
    r"^\s*\d+\.\s*([+-]?\d+(?:\.\d+)?) to ([+-]?\d+(?:\.\d+)?) deg:\s*"
    r"(?:(no data)|closest (inf|\d+(?:\.\d+)?)(?: m at ([+-]?\d+(?:\.\d+)?) deg)?)",
    re.MULTILINE,
)
_RANGE_MAX = re.compile(r"inf = nothing within (\d+(?:\.\d+)?) m")
_IMAGE_HASH = re.compile(r"[0-9a-f]{64}")  # images are stored under their sha256 (llmnav.runs.runlog)


@dataclass
class Sector:
    """One LiDAR sector as the model was told it; angles [deg], positive = left."""

    start_deg: float
    end_deg: float
    min_m: float | None  # [m] None = no data; inf = nothing in range
    angle_deg: float | None


@dataclass
class LidarView:
    """The sectors told to the model, parsed back from the observation's text."""

    front_m: float | None
    sectors: list[Sector]
    range_max_m: float  # [m] radius of the polar plot


@dataclass
class MessageView:
    """One chat message of a request."""

    role: str
    text: str
    images: list[str] = field(default_factory=list)  # image hashes


@dataclass
class CallView:
    """One model call: what was new in the prompt, the whole request, the raw reply and its cost."""

    purpose: str
    new_messages: list[MessageView]
    messages: list[MessageView]
    reply: str | None
    error: str | None
    model: str | None
    latency_s: float | None
    tokens: dict[str, Any]  # prompt_tokens, completion_tokens and whatever other *_tokens the backend logged
    t_wall: float | None = None
    # A scoring call writes no reply: the log-probability [nats] and token count of each continuation.
    scores: list[tuple[str, float, int]] = field(default_factory=list)
    content_free: bool = False  # its prompt holds the content-free task (the PMI's baseline), not the user's


@dataclass
class StepView:
    """One decision and everything logged about it."""

    index: int  # 0-based position on the page
    label: str  # "Step 3", "Leg 1", "Suggestion 12", "State APPROACH"
    step: Any  # the logged step value (None for FSM suggestions)
    pose_before: list[float] | None = None
    pose_after: list[float] | None = None
    image: str | None = None  # hash of the camera image sent
    lidar: LidarView | None = None
    lidar_text: str | None = None
    detections: list[dict[str, Any]] = field(default_factory=list)
    calls: list[CallView] = field(default_factory=list)
    guards: list[dict[str, Any]] = field(default_factory=list)  # every verdict, vetoes included
    actions: list[dict[str, Any]] = field(default_factory=list)
    attempts: list[dict[str, Any]] = field(default_factory=list)  # waypoint generation attempts
    replans: list[dict[str, Any]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)  # other planner records, one line each
    missing: list[str] = field(default_factory=list)
    verdict: str | None = None  # FSM suggestion outcome
    t_sim: float | None = None
    scores: dict[str, float] = field(default_factory=dict)  # a scored decision: each landmark's PMI [nats]
    rule: str | None = None  # a scored decision: which rule chose
    # hybrid: the frontiers on the menu (where, what is near, utility; PMI and value where scored)
    frontiers: list[dict[str, Any]] = field(default_factory=list)
    chosen: int | None = None  # a scored decision: the option number it chose

    @property
    def vetoes(self) -> list[dict[str, Any]]:
        """The safety vetoes of this decision."""
        return [g for g in self.guards if g.get("outcome") == "veto"]

    @property
    def latency_s(self) -> float:
        """Model time of the decision [s]."""
        return sum(c.latency_s or 0.0 for c in self.calls)

    @property
    def tokens(self) -> dict[str, int]:
        """Token counts of the decision, summed over its calls."""
        return sum_tokens(self.calls)

    @property
    def action_text(self) -> str:
        """The executed action(s) in a few words."""
        if not self.actions:
            return self.verdict or "no action"
        return "; ".join(describe_action(a) for a in self.actions[:4]) + (
            f" (+{len(self.actions) - 4} more)" if len(self.actions) > 4 else ""
        )

    @property
    def reasoning(self) -> str:
        """The model's reasoning on its last accepted answer, on one line (empty when there is none).

        The guard logs the value it accepted; a log written before it did has only the replies, parsed again.
        """
        logged = [g for g in self.guards if "value" in g]
        if logged:
            accepted = next((g.get("value") for g in reversed(logged) if g.get("outcome") == "ok"), None)
            return one_line_reasoning(accepted)
        for call in reversed(self.calls):
            if call.reply:
                return reasoning_of(call.reply)
        return ""


@dataclass
class CommandProfile:
    """A velocity planner's records: the command profile and the suggestion outcomes over time."""

    t: list[float]
    base: list[list[float]]
    raw: list[list[float] | None]
    fused: list[list[float]]
    suggestions: list[dict[str, Any]]  # t_recv, verdict, detail, latency_ms
    states: list[dict[str, Any]]  # t_sim, previous, state, sign


@dataclass
class RunView:
    """A run folder arranged for its page."""

    run_dir: Path
    record: RunRecord
    summary: dict[str, Any]
    scenario: Scenario | None
    task: Task | None
    steps: list[StepView]
    trajectory: list[list[float]]
    oracle: list[tuple[float, float]] | None
    profile: CommandProfile | None  # a planner that declares `velocity_view`
    missing: list[str]  # what the whole run lacks (summary, end event, images ...)
    image_files: dict[str, Path]  # hash -> file for the images that exist
    declared: Declarations  # what its planner declares, or what the log shows when it is not installed

    @property
    def config(self) -> dict[str, Any]:
        """The run's configuration line."""
        return self.record.config

    @property
    def targets(self) -> list[tuple[float, float]]:
        """The task's target points [m] (none for a task without targets or a scenario that did not load)."""
        if self.scenario is None or self.task is None or not self.task.targets:
            return []
        try:
            return [(float(p[0]), float(p[1])) for p in self.scenario.target_points(self.task)]
        except KeyError:  # a target object the scenario does not have
            return []

    @property
    def success_radius_m(self) -> float:
        """[m] The radius success was judged at (the summary's, else the default)."""
        value = _number(self.summary.get("success_radius_m"))
        return value if value is not None and value > 0 else SUCCESS_RADIUS_M

    @property
    def header(self) -> dict[str, Any]:
        """The page header's fields (absent ones are None)."""
        config, summary = self.config, self.summary
        task = as_dict(config.get("task"))
        options = as_dict(config.get("options"))
        models = sorted({c.model for s in self.steps for c in s.calls if c.model})
        calls = [c for s in self.steps for c in s.calls]
        oracle_m = polyline_length(self.oracle) if self.oracle else None
        path_m = summary.get("path_length_m")
        ratio = path_m / oracle_m if isinstance(path_m, (int, float)) and oracle_m else None
        return {
            "task": task.get("text") or summary.get("task_text"),
            "task_id": task.get("id"),
            "wording": task.get("wording"),
            "scenario": config.get("scenario"),
            "start_pose_index": config.get("start_pose_index"),
            "planner": config.get("planner") or options.get("planner"),
            "backend": config.get("backend"),
            "models": models,
            "information": config.get("information") or summary.get("information"),
            "outcome": summary.get("outcome"),
            "reason": summary.get("reason"),
            "score": summary.get("score"),
            "success": summary.get("success"),
            "path_length_m": summary.get("path_length_m"),
            "oracle_length_m": oracle_m,
            "oracle_ratio": ratio,
            "iterations": summary.get("iterations"),
            "llm_calls": len(calls),
            "model_time_s": sum(c.latency_s or 0.0 for c in calls),
            "tokens": sum_tokens(calls),
            "json_errors": summary.get("json_errors"),
            "safety_vetoes": summary.get("safety_vetoes"),
            "sim_time_s": summary.get("sim_time_s"),
            "seed": config.get("seed"),
        }


# --- small readers -------------------------------------------------------------------------------


def as_dict(value: Any) -> dict[str, Any]:
    """A logged mapping; an empty one for anything else (a log may hold odd values)."""
    return value if isinstance(value, dict) else {}


def sum_tokens(calls: list[CallView]) -> dict[str, int]:
    """Token counts summed over calls, per kind (only the kinds some call reported)."""
    total: dict[str, int] = {}
    for call in calls:
        for name, value in call.tokens.items():
            if isinstance(value, int) and not isinstance(value, bool):
                total[name] = total.get(name, 0) + value
    return total


def polyline_length(points: list[tuple[float, float]] | list[list[float]]) -> float:
    """Length [m] of a polyline."""
    return sum(math.dist(a[:2], b[:2]) for a, b in zip(points, points[1:], strict=False))


def reasoning_of(reply: str) -> str:
    """The `reasoning` field of a reply parsed again (logs from before the guard logged its value)."""
    # deferred: the guard's parser brings pydantic (about 0.1 s), only for old logs
    from llmnav.guard.parse import parse_answer

    result: Any = parse_answer(reply, dict[str, Any])
    return one_line_reasoning(result.value)


def one_line_reasoning(value: Any) -> str:
    """The `reasoning` field of an answer's value, on one line; empty when the value has none."""
    text = value.get("reasoning") if isinstance(value, dict) else None
    if not isinstance(text, str):
        return ""
    line = " ".join(text.split())
    return line if len(line) <= REASONING_CHARS else line[: REASONING_CHARS - 1] + "…"


def describe_action(action: dict[str, Any]) -> str:
    """`FRONT 1.5`, `GOTO 2.3 (Go to room 101)`, `WAYPOINT [1.0, 2.0]`, plus what stopped it."""
    command = action.get("command")
    params = action.get("parameters")
    if command is None and isinstance(action.get("action"), str):
        text = action["action"]  # a Gymnasium episode logs the action as one phrase: `BACK 4.55 m`, `COMPLETE`
    elif command is None:
        text = "?"
    elif params is None or (params in (0, 0.0) and command == "COMPLETE"):
        text = str(command)
    else:
        text = f"{command} {params}"
    if action.get("option"):
        text += f" ({action['option']})"
    if action.get("vetoed"):
        text += " — vetoed"
    if action.get("collided"):
        text += f" — collided with {action.get('collision_with') or 'an obstacle'}"
    elif action.get("stopped_reason"):
        text += f" — stopped: {action['stopped_reason']}"
    return text


def as_pose(value: Any) -> list[float] | None:
    """A logged pose [x, y(, yaw)] as floats; None for anything else (a log may hold odd values)."""
    return logged_pose(value) if isinstance(value, list) else None


def _number(value: Any) -> float | None:
    """A logged number as a float; None for anything else, NaN and infinities included (a log may hold odd values)."""
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    return float(value) if ok else None


def logged_lidar(sectors: Any, front_m: Any, range_m: Any) -> LidarView | None:
    """The sectors of an observation event's `lidar_sectors` (`planners.observe.sectors_log`); None if absent."""
    if not isinstance(sectors, list) or not sectors:
        return None
    out: list[Sector] = []
    for item in sectors:
        if not isinstance(item, dict):
            return None
        start, end, rays = _number(item.get("start_deg")), _number(item.get("end_deg")), _number(item.get("rays"))
        closest, angle = _number(item.get("closest_m")), _number(item.get("angle_deg"))
        if start is None or end is None or rays is None:
            return None
        value = None if rays == 0 else (closest if closest is not None else math.inf)
        out.append(Sector(start, end, value, angle))
    finite = [s.min_m for s in out if s.min_m is not None and math.isfinite(s.min_m)]
    range_max = float(range_m) if isinstance(range_m, (int, float)) and math.isfinite(range_m) else max([*finite, 1.0])
    return LidarView(front_m if isinstance(front_m, (int, float)) else None, out, range_max)


def parse_lidar(text: Any, front_m: Any) -> LidarView | None:
    """The sectors of an observation's LiDAR text (`llmnav.sensing.perception.LidarSummary.text`); None if absent."""
    if not isinstance(text, str) or not text:
        return None
    sectors: list[Sector] = []
    for match in _SECTOR_LINE.finditer(text):
        start, end, no_data, dist, angle = match.groups()
        value = None if no_data else (math.inf if dist == "inf" else float(dist))
        sectors.append(Sector(float(start), float(end), value, None if angle is None else float(angle)))
    if not sectors:
        return None
    found = _RANGE_MAX.search(text)
    finite = [s.min_m for s in sectors if s.min_m is not None and math.isfinite(s.min_m)]
    range_max = float(found.group(1)) if found else max([*finite, 1.0])
    return LidarView(front_m if isinstance(front_m, (int, float)) else None, sectors, range_max)


def _messages(request: Any) -> list[MessageView]:
    out: list[MessageView] = []
    raw = request.get("messages") if isinstance(request, dict) else None
    for message in raw if isinstance(raw, list) else []:
        if not isinstance(message, dict):
            continue
        images = [str(h) for h in message.get("images") or [] if isinstance(h, str)]
        out.append(MessageView(str(message.get("role", "?")), str(message.get("text", "")), images))
    return out


def _call_view(event: dict[str, Any], previous: list[MessageView]) -> CallView:
    """A call; its new messages are those after the part it shares with the previous request.

    The model's own earlier answers (assistant messages) are not new to it and are left out.
    """
    messages = _messages(event.get("request"))
    shared = 0
    while shared < min(len(messages), len(previous)) and messages[shared] == previous[shared]:
        shared += 1
    new = [m for m in messages[shared:] if m.role != "assistant"]
    reply = event.get("reply") if isinstance(event.get("reply"), dict) else None
    tokens: dict[str, Any] = {}
    if reply is not None:
        for source in (reply, reply.get("meta") if isinstance(reply.get("meta"), dict) else {}):
            for key, value in source.items():
                if key.endswith("tokens") and value is not None:
                    tokens.setdefault(key, value)
    latency = reply.get("latency_s") if reply else None
    scores = _scores(event.get("request"), reply)
    return CallView(
        purpose=str(event.get("purpose") or "call"),
        new_messages=new,
        messages=messages,
        reply=(reply["text"] if isinstance(reply.get("text"), str) else "") if reply else None,
        error=str(event["error"]) if event.get("error") is not None else None,
        model=str(reply["model"]) if reply and reply.get("model") else None,
        latency_s=float(latency) if isinstance(latency, (int, float)) else None,
        tokens=tokens,
        t_wall=event.get("t_wall"),
        scores=scores,
        content_free=bool(scores) and any(CONTENT_FREE_LINE in m.text for m in messages),
    )


CONTENT_FREE_LINE = f"Task: {CONTENT_FREE_TASK}\n"  # how a scoring prompt names the content-free task


def _scores(request: Any, reply: dict[str, Any] | None) -> list[tuple[str, float, int]]:
    """(continuation, log-probability [nats], tokens) of a scoring call; [] for a call that wrote a reply."""
    logged = reply.get("scores") if reply else None
    texts = request.get("continuations") if isinstance(request, dict) else None
    if not isinstance(logged, list) or not isinstance(texts, list) or len(texts) != len(logged):
        return []
    out = []
    for text, item in zip(texts, logged, strict=True):
        value = item if isinstance(item, list) and len(item) == 2 else [None, None]
        logprob, count = _number(value[0]), _number(value[1])
        if logprob is None:
            return []
        out.append((str(text), logprob, int(count or 0)))
    return out


def _planner_note(event: dict[str, Any]) -> str:
    """One line for a planner record shown in a decision's notes."""
    fields = {k: v for k, v in event.items() if k not in ("type", "kind", "step", "t_wall", "t_sim")}
    detail = ", ".join(f"{k}={v}" for k, v in fields.items())
    return f"{event.get('kind', 'planner')}: {detail}" if detail else str(event.get("kind", "planner"))


# --- grouping ------------------------------------------------------------------------------------


def _suggestion_steps(record: RunRecord) -> list[StepView]:
    """A velocity planner's decisions: one per suggestion (paired with its verdict in order), else per state change."""
    calls = record.of_type("llm_call")
    verdicts = [e for e in record.of_type("planner") if e.get("kind") == "suggestion"]
    steps: list[StepView] = []
    previous: list[MessageView] = []
    if calls:
        for i, event in enumerate(calls):
            call = _call_view(event, previous)
            previous = call.messages
            step = StepView(i, f"Suggestion {i + 1}", None, calls=[call], t_sim=event.get("t_sim"))
            if i < len(verdicts):
                v = verdicts[i]
                step.verdict = str(v.get("verdict"))
                step.guards.append({"outcome": v.get("verdict"), "error": v.get("detail"), "attempt": 1})
                step.notes.append(
                    f"received at t={v.get('t_recv')} s, stamped {v.get('stamp')} s, latency {v.get('latency_ms')} ms"
                )
            else:
                step.missing.append("no verdict logged (the run ended before the answer was due)")
            steps.append(step)
        _place_by_time(steps, record)
        return steps
    for i, event in enumerate(e for e in record.of_type("planner") if e.get("kind") == "fsm_state"):
        pose = as_pose(event.get("pose"))
        step = StepView(i, f"State {event.get('state')}", None, pose_before=pose, pose_after=pose)
        step.t_sim = event.get("t_sim")
        step.notes.append(f"{event.get('previous')} → {event.get('state')} (sign {event.get('sign')})")
        step.verdict = f"{event.get('previous')} → {event.get('state')}"
        steps.append(step)
    return steps


def _reading_ahead(record: RunRecord) -> bool:
    """Whether the log numbers each reading one step before the action taken on it.

    A Gymnasium episode (`llmnav.gym.RunLog`) logs the reading of `reset` as step 0 and action k with the
    reading that follows it; llmnav's planners log the reading and the action of a decision under one step.
    """
    observed = [e["step"] for e in record.of_type("observation") if isinstance(e.get("step"), int)]
    acted = [e["step"] for e in record.of_type("action") if isinstance(e.get("step"), int)]
    return bool(observed and acted) and min(observed) == min(acted) - 1


def _place_by_time(steps: list[StepView], record: RunRecord) -> None:
    """Give decisions without poses the trajectory sample logged last before them (by sim time)."""
    samples = [
        (float(e["t_sim"]), pose)
        for e in record.of_type("pose")
        if isinstance(e.get("t_sim"), (int, float)) and (pose := as_pose(e.get("pose"))) is not None
    ]
    times = [t for t, _ in samples]
    for step in steps:
        if step.pose_before is None and isinstance(step.t_sim, (int, float)) and samples:
            index = max(0, bisect.bisect_right(times, float(step.t_sim)) - 1)
            step.pose_before = step.pose_after = samples[index][1]


def _stepped(record: RunRecord, noun: str) -> list[StepView]:
    """Decisions by logged step value, in the order they first appear, labelled `noun` and the value."""
    by_step: dict[Any, StepView] = {}
    previous: list[MessageView] = []
    ahead = _reading_ahead(record)
    acted = {e["step"] for e in record.of_type("action") if isinstance(e.get("step"), int)}
    for event in record.events:
        kind = event.get("type")
        if kind not in ("observation", "llm_call", "guard", "action", "planner", "decision") or "step" not in event:
            continue
        key = event.get("step")
        if key is None or isinstance(key, (dict, list)):
            continue
        if ahead and kind == "observation" and isinstance(key, int):
            key += 1  # the reading the next action was chosen from belongs to that action's decision
            if key not in acted:
                continue  # the reading after the last action: the end pose, no decision of its own
        step = by_step.get(key)
        if step is None:
            step = by_step[key] = StepView(len(by_step), f"{noun} {key}", key, t_sim=event.get("t_sim"))
        if kind == "observation":
            step.pose_before = step.pose_before or as_pose(event.get("pose"))
            image = event.get("image")
            step.image = step.image or (image if isinstance(image, str) else None)
            text = event.get("lidar_text")
            if not isinstance(text, str):
                text = event.get("text")  # a Gymnasium episode's text observation: what the agent read
            step.lidar_text = text if isinstance(text, str) else None
            front = event.get("lidar_front_m")
            step.lidar = logged_lidar(event.get("lidar_sectors"), front, event.get("lidar_range_m")) or parse_lidar(
                event.get("lidar_text"), front
            )  # logs written before the sectors were logged as data carry them only as text
            step.detections = [d for d in event.get("detections") or [] if isinstance(d, dict)]
        elif kind == "llm_call":
            call = _call_view(event, previous)
            previous = call.messages
            step.calls.append(call)
            if step.image is None:  # a planner that logs no observation still sends images
                step.image = next((h for m in call.new_messages for h in m.images), None)
        elif kind == "decision":
            pmi = event.get("pmi")
            step.scores = {
                str(k): float(v)
                for k, v in (pmi.items() if isinstance(pmi, dict) else [])
                if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
            }
            step.rule = event.get("rule") if isinstance(event.get("rule"), str) else None
            option = event.get("option")
            step.chosen = option if isinstance(option, int) and not isinstance(option, bool) else None
            rows = event.get("frontiers")
            step.frontiers = [r for r in (rows if isinstance(rows, list) else []) if isinstance(r, dict)]
        elif kind == "guard":
            step.guards.append(event)
        elif kind == "action":
            step.actions.append(event)
            if step.pose_before is None:
                step.pose_before = as_pose(event.get("pose_before"))
            step.pose_after = as_pose(event.get("pose_after")) or step.pose_after
        elif event.get("kind") == "waypoint_attempt":
            step.attempts.append(event)
        elif event.get("kind") == "replan":
            step.replans.append(event)
        else:
            step.notes.append(_planner_note(event))
    return list(by_step.values())


def _profile(record: RunRecord) -> CommandProfile:
    planner = record.of_type("planner")
    cmds = [e for e in planner if e.get("kind") == "cmd" and well_formed_cmd(e)]
    return CommandProfile(
        t=[float(e.get("t_sim", 0.0)) for e in cmds],
        base=[e["base"] for e in cmds],
        raw=[e.get("raw") if isinstance(e.get("raw"), list) else None for e in cmds],
        fused=[e["fused"] if isinstance(e.get("fused"), list) else e["base"] for e in cmds],
        suggestions=[e for e in planner if e.get("kind") == "suggestion"],
        states=[e for e in planner if e.get("kind") == "fsm_state"],
    )


def _declarations(record: RunRecord) -> Declarations:
    """What the run's planner declares, through the registry; the log's own content when it is not installed."""
    # deferred: the planner registry brings pydantic (about 0.1 s), only when a run is read
    from llmnav.planners.base import planner_class

    name = record.config.get("planner") or as_dict(record.config.get("options")).get("planner")
    try:
        return declarations_of(planner_class(str(name)))
    except BadInputError:
        kinds = {e.get("kind") for e in record.of_type("planner")}
        return Declarations(
            velocity_view=bool(kinds & {"cmd", "suggestion", "fsm_state"}),
            asks_model_every_decision=any(e.get("step") is not None for e in record.of_type("llm_call")),
        )


def _mark_missing(steps: list[StepView], model_planner: bool) -> None:
    """Say what each decision lacks (a killed run stops mid-decision); `model_planner`: each asks the model."""
    for step in steps:
        if step.verdict is not None:
            continue
        # A scored decision writes no answer to guard, and names scored before cost no call at all.
        scored = step.rule is not None
        if model_planner and not scored and not step.calls:
            step.missing.append("no model call logged for this decision")
        if model_planner and not scored and step.calls and not step.guards:
            step.missing.append("no guard verdict logged")
        if not step.actions:
            step.missing.append("no action logged (the run ended before one was executed)")


def _task(config: dict[str, Any], scenario: Scenario | None) -> Task | None:
    """The run's task: the scenario's own when the id is one of its tasks, else rebuilt from the record."""
    # deferred: pydantic and yaml (about 0.15 s) load only when a run is read
    from pydantic import ValidationError

    from llmnav.world.scenario import Task

    record = as_dict(config.get("task"))
    if scenario is not None and record.get("id"):
        try:
            return scenario.task(str(record["id"]))
        except KeyError:
            pass
    known = {k: record[k] for k in ("id", "text", "kind", "difficulty", "targets") if k in record}
    try:
        return Task.model_validate(known)
    except ValidationError:
        return None


def build_run_view(run_dir: Path) -> RunView:
    """Read a run folder for its page; raises BadInputError when it is no readable run."""
    # deferred: run folders bring pydantic and yaml (about 0.15 s), only when a run is read
    from llmnav.runs.folders import run_from_record, scenario_of

    run_dir = Path(run_dir)
    record = read_run(run_dir)
    missing: list[str] = []
    try:
        summary = run_from_record(record).summary  # the log read once, above
    except (AttributeError, IndexError, KeyError, TypeError, ValueError) as err:
        # Malformed fields (a pose with one number, a string for a number) defeat the metrics; the page
        # still shows every event, and says why the figures are absent.
        summary = dict(record.summary or {})
        missing.append(f"the run's figures cannot be computed from this log ({type(err).__name__}: {err})")
    scenario = scenario_of(record.config)
    declared = _declarations(record)
    steps = _suggestion_steps(record) if declared.velocity_view else _stepped(record, declared.decision_noun)
    _mark_missing(steps, declared.asks_model_every_decision)
    if not record.complete:
        missing.append("the run has no end event: it was cut short (killed or still running)")
    if record.summary is None:
        missing.append("summary.json is missing: the figures above are recomputed from the log")
    if record.torn_lines:
        missing.append(f"{record.torn_lines} incomplete last line(s) of the log were ignored")
    if scenario is None:
        missing.append(f"scenario {record.config.get('scenario')!r} cannot be loaded: no map is drawn")
    images: dict[str, Path] = {}
    wanted = {s.image for s in steps if s.image}
    for digest in sorted(wanted):
        if not _IMAGE_HASH.fullmatch(digest):  # a hand-made log could name ../../anything: only hashes
            continue
        path = run_dir / IMAGES_DIR / f"{digest}.jpg"
        if path.is_file():
            images[digest] = path
    if len(images) < len(wanted):
        missing.append(f"{len(wanted) - len(images)} camera image(s) referenced by the log are missing")
    task = _task(record.config, scenario)
    start = as_pose(record.config.get("start_pose"))
    oracle = None
    if scenario is not None and task is not None and start is not None and len(start) >= 3:
        oracle = oracle_points(scenario, task, start)
    if not steps:
        missing.append("no decision was logged")
    return RunView(
        run_dir=run_dir,
        record=record,
        summary=summary,
        scenario=scenario,
        task=task,
        steps=steps,
        trajectory=[p for p in (as_pose(e.get("pose")) for e in record.of_type("pose")) if p is not None],
        oracle=oracle,
        profile=_profile(record) if declared.velocity_view else None,
        missing=missing,
        image_files=images,
        declared=declared,
    )
