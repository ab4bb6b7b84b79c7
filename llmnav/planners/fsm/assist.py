"""The FSM's model assist: the state message, the model's calls, the guard's judgment and the TTL pipeline.

The model's side is kept small, because its cost is almost all prompt reading and decoding: the state
message is one short line (`stop 1.23 -0.10 45 -150`: class, distance [m] and offset to 2 decimals, the
baseline v [mm/s] and w [mrad/s]; the legend is in the fixed system prompt, served from the prompt
cache), and the answer is `[v, w]` in whole mm/s and mrad/s, whose JSON Schema carries the kinematic
box as minimum/maximum, so a grammar-constrained backend cannot produce an out-of-box value. The guard
judges every answer against that same box (`VelocityBox`): one check, whose `guard` event and the FSM's
counters agree. The stamp and the deadline stay on the controller's side.

A proposal is used only if well-formed and inside the box (the guard), and fresh (t_recv - t_stamp <=
TTL): it is then held until a newer one arrives or it expires. `--ttl auto` sets the TTL from the
latencies seen so far (p95 x 1.2, within [TTL_AUTO_MIN_MS, TTL_AUTO_MAX_MS]) and logs each change.

Where the model runs: between ticks with the simulation frozen (virtual time; its latency is charged to
simulation time), in a worker thread, or, for an engine computing inside this process, in a process of its
own polled by the loop thread (llmnav.backends.isolated). An answer is judged by the guard when it is
received, before the tick that may use it starts: judging text is the assist's work, not the controller's;
the tick only checks its freshness and uses it. Its `guard` and `suggestion` events are written after the
tick has published its command, in the order they always had.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from llmnav.core.chat import ChatRequest, ChatResult, Message
from llmnav.errors import LlmnavError
from llmnav.guard.ask import CallContext, ask_guarded
from llmnav.planners.fsm.answers import VelocityBox, VelocityMilli, velocity_schema
from llmnav.planners.fsm.control import FsmConfig
from llmnav.planners.fsm.workers import ProcessWorker, ThreadWorker
from llmnav.planners.observe import call_model, llm_call_fields
from llmnav.planners.prompting import render

if TYPE_CHECKING:
    from llmnav.guard.ask import GuardedAnswer
    from llmnav.planners.base import DriveOptions, EpisodeContext
    from llmnav.planners.fsm.stats import FsmStats
    from llmnav.runs.runlog import RunLog

ANSWER_MAX_TOKENS = 12  # `[-60,-800]` is 10 tokens with its end token; a margin, no runaway
Verdict = Literal["accepted", "stale", "bounds", "parse", "error"]
Event = tuple[str, dict[str, Any]]

TTL_AUTO_FACTOR = 1.2  # `--ttl auto`: TTL = p95 of the observed model latencies x this
TTL_AUTO_MIN_MS = 100.0  # [ms] floor: a suggestion older than this is stale whatever the model's speed
TTL_AUTO_MAX_MS = 2000.0  # [ms] ceiling: 100 ticks; older commands describe a different situation
TTL_AUTO_MIN_SAMPLES = 5  # latencies seen before the TTL adapts (the start value is `ttl_ms`)
TTL_AUTO_STEP = 0.1  # a new TTL is adopted (and logged) when it differs from the current one by > 10 %


@dataclass(frozen=True)
class Judged:
    """The guard's verdict on one answer text, and the `guard` event it logged (held until written)."""

    value: tuple[float, float] | None  # (v [m/s], w [rad/s]) when inside the box
    outcome: str  # the guard's: ok | parse | schema | bounds
    detail: str
    events: tuple[Event, ...] = ()


@dataclass
class Suggestion:
    """A model answer on its way to the controller."""

    stamp: float  # [s] sim time of the state it answers
    ready_at: float  # [s] sim time from which it may be used
    text: str | None  # raw answer (None when the call failed)
    latency_s: float
    error: str | None = None
    judged: Judged | None = None  # None when the call failed


@dataclass
class HeldSuggestion:
    """An accepted suggestion, sample-and-hold until newer or expired."""

    stamp: float
    v: float
    w: float


def answer_box(cfg: FsmConfig) -> VelocityBox:
    """The admissible box of an answer, in its whole milli-units."""
    return VelocityBox.of(cfg.v_min, cfg.v_max, cfg.w_max)


def answer_schema(cfg: FsmConfig) -> dict[str, Any]:
    """The answer's JSON Schema, with the admissible box as integer bounds in mm/s and mrad/s."""
    return velocity_schema(cfg.v_min, cfg.v_max, cfg.w_max)


def system_prompt(cfg: FsmConfig) -> str:
    """The fixed system prompt: the state line's legend and the box, in the answer's units."""
    return render(
        "fsm_velocity",
        v_min=round(cfg.v_min * 1000),
        v_max=round(cfg.v_max * 1000),
        w_max=round(cfg.w_max * 1000),
        d_goal=cfg.d_goal,
    )


def state_message(sign: str | None, distance_m: float, offset: float, base_v: float, base_w: float) -> str:
    """The model's state line: class, distance [m], offset, baseline v [mm/s] and w [mrad/s].

    Two decimals for distance and offset (the detector is not better than that); whole milli-units for
    the command, the units of the answer, so the model compares like with like.
    """
    return f"{sign or 'none'} {distance_m:.2f} {offset:+.2f} {round(base_v * 1000)} {round(base_w * 1000)}"


def suggestion_request(prompt: str, schema: dict[str, Any], text: str, opts: DriveOptions) -> ChatRequest:
    """The request for one state line."""
    return ChatRequest(
        messages=(Message("system", prompt), Message("user", text)),
        json_schema=schema,
        temperature=opts.temperature,
        max_tokens=min(opts.max_tokens, ANSWER_MAX_TOKENS),
        seed=opts.seed,
    )


def judge(text: str, box: VelocityBox, request: ChatRequest | None = None) -> Judged:
    """The guarded ask loop on a reply already in hand, with the box as its bounds.

    No correction turns: the loop cannot wait. Its `guard` event is kept in the result, for the loop to
    write once the tick that uses it has published its command.
    """
    events: list[Event] = []

    def no_call(asked: ChatRequest, purpose: str) -> ChatResult:
        raise AssertionError("a reply in hand with no correction turns never calls the model")

    deferred = CallContext(no_call, lambda kind, **fields: events.append((kind, fields)))
    asked = request or ChatRequest(messages=())
    answer: GuardedAnswer[VelocityMilli] = ask_guarded(
        deferred, asked, VelocityMilli, box, 0, reply=text, purpose="suggestion"
    )
    result = answer.result
    value = None if result.value is None else (result.value.v / 1000.0, result.value.w / 1000.0)
    return Judged(value, result.outcome, result.error or result.outcome, tuple(events))


def verdict(
    text: str | None, judged: Judged | None, stamp: float, t_recv: float, ttl_s: float
) -> tuple[Verdict, tuple[float, float] | None, str]:
    """The FSM's verdict on a judged answer: (verdict, (v [m/s], w [rad/s]) if usable, detail).

    Order: parse, freshness, bounds: an answer the guard rejected for its shape counts as `parse`, one it
    rejected for the box as `bounds` unless it is also stale.
    """
    if text is None or judged is None:
        return "error", None, "model call failed"
    if judged.value is None and judged.outcome != "bounds":
        return "parse", None, judged.detail
    if t_recv - stamp > ttl_s:
        return "stale", None, f"{(t_recv - stamp) * 1000:.0f} ms old > TTL {ttl_s * 1000:.0f} ms"
    if judged.value is None:
        return "bounds", None, judged.detail
    return "accepted", judged.value, ""


def check_suggestion(
    text: str | None, stamp: float, t_recv: float, ttl_s: float, cfg: FsmConfig
) -> tuple[Verdict, tuple[float, float] | None, str]:
    """Judge a model answer as the episode does (guard with the box, then freshness); see `verdict`."""
    judged = None if text is None else judge(text, answer_box(cfg))
    return verdict(text, judged, stamp, t_recv, ttl_s)


def adaptive_ttl_ms(latencies_ms: list[float]) -> float | None:
    """`--ttl auto`: p95 of the observed latencies x TTL_AUTO_FACTOR, bounded; None while too few."""
    if len(latencies_ms) < TTL_AUTO_MIN_SAMPLES:
        return None
    p95 = float(np.percentile(np.asarray(latencies_ms), 95))
    return min(max(p95 * TTL_AUTO_FACTOR, TTL_AUTO_MIN_MS), TTL_AUTO_MAX_MS)


@dataclass
class AssistPipeline:
    """One episode's road from state line to held suggestion: publish, receive and judge, deliver, expire.

    `deliver` and `in_force` run inside the tick (freshness and hold are arithmetic); everything that
    reads text or builds log records runs outside it (`receive` before the tick, `write` after it).
    """

    ctx: EpisodeContext
    cfg: FsmConfig
    stats: FsmStats
    ttl_s: float = 0.0  # [s] the TTL in force
    box: VelocityBox = field(init=False)
    schema: dict[str, Any] = field(init=False)
    prompt: str = field(init=False)
    worker: ThreadWorker | ProcessWorker | None = None
    pending: Suggestion | None = None
    in_flight: bool = False
    held: HeldSuggestion | None = None
    sent: ChatRequest | None = None  # the request in flight (at most one), for the guard's record
    last_publish: float = -math.inf
    notes: list[Event] = field(default_factory=list)  # events of a tick written before its state changes
    outbox: list[Event | Callable[[], Event]] = field(default_factory=list)  # written after them

    def __post_init__(self) -> None:
        self.box = answer_box(self.cfg)
        self.schema = answer_schema(self.cfg)
        self.prompt = system_prompt(self.cfg)
        self.ttl_s = self.ctx.options.ttl_ms / 1000.0

    # --- before the first tick ----------------------------------------------------------------------
    def start(self) -> None:
        """Start the worker the timing mode needs; a schema the backend cannot compile raises here."""
        ctx, opts, backend = self.ctx, self.ctx.options, self.ctx.backend
        assert backend is not None
        if opts.realtime and backend.engine_in_process:
            warm_up = self.request(state_message("stop", 1.0, 0.0, 0.0, 0.0))
            self.worker = ProcessWorker.start(backend, self.schema, warm_up, self._record)  # checks the schema
            self.stats.model_in = "process"
            return
        backend.check_schema(self.schema)  # a grammar that cannot compile ends the episode before tick 0
        if opts.realtime:
            self.worker = ThreadWorker(lambda request: call_model(ctx, request, purpose="suggestion", step=None))
            self.stats.model_in = "thread"

    def warm(self) -> None:
        """Pay the guard's one-time costs (imports, schema build) before the clock starts."""
        judge("[0,0]", self.box)
        judge("```json\n{}\n```", self.box)

    def request(self, text: str) -> ChatRequest:
        """The request for one state line."""
        return suggestion_request(self.prompt, self.schema, text, self.ctx.options)

    # --- around each tick ---------------------------------------------------------------------------
    def receive(self, now: float) -> None:
        """Realtime: take the worker's next answer and judge it (before the tick; never waits)."""
        if self.worker is None or self.pending is not None:
            return
        polled = self.worker.poll()
        if polled is None:
            return
        stamp, result, error, latency = polled
        died = self.worker.died
        if died is not None and self.stats.assist_failed is None:
            self._degrade(died)
        fixed = self.ctx.options.model_latency
        if isinstance(fixed, float | int):  # cannot be faster than reality: a floor
            latency = max(latency, fixed / 1000.0)
        text = result.text if result else None
        self.pending = Suggestion(stamp, max(now, stamp + latency), text, latency, error, self._judge(text))

    def deliver(self, now: float) -> None:
        """In the tick: the answer due now gets its verdict and, if accepted, is held; expired ones drop."""
        pending = self.pending
        if pending is not None and now >= pending.ready_at - 1e-9:
            self.pending, self.in_flight = None, False
            stats = self.stats
            stats.suggestions += 1
            stats.model_latency_ms.append(pending.latency_s * 1000.0)
            judged = pending.judged
            found, value, detail = verdict(pending.text, judged, pending.stamp, now, self.ttl_s)
            if value is not None:
                stats.accepted += 1
                self.held = HeldSuggestion(pending.stamp, *value)
            else:
                stats.rejected[found] += 1
            if judged is not None:
                self.outbox.extend(judged.events)
            self.outbox.append(lambda: _suggestion_event(pending, now, found, detail))
            if self.ctx.options.ttl_auto:
                self._adapt_ttl()
        held = self.held
        if held is not None and now - held.stamp > self.ttl_s:
            self.held = None  # expired: the baseline applies at once

    def in_force(self) -> tuple[float, float] | None:
        """The held suggestion (v [m/s], w [rad/s]), if any."""
        held = self.held
        return None if held is None else (held.v, held.w)

    def drop(self) -> None:
        """The FSM left APPROACH: the held suggestion no longer applies, nor (virtual time) the pending one.

        A worker's answer still arrives and is judged (likely stale).
        """
        self.held = None
        if self.worker is None:
            self.pending, self.in_flight = None, False

    def publish(self, now: float, text: str) -> None:
        """Send the state line when none is in flight and the publish period has passed (never once failed)."""
        if self.stats.assist_failed is not None:
            return
        if self.in_flight or now - self.last_publish < 1.0 / self.cfg.publish_hz - 1e-9:
            return
        request = self.sent = self.request(text)
        self.last_publish, self.in_flight = now, True
        if self.worker is not None:
            self.worker.submit(now, request)
        else:
            self.pending = self._call_virtual(request, now)

    def write_notes(self, log: RunLog) -> None:
        """The events the tick logged before its state changes (a TTL change)."""
        for kind, fields in self.notes:
            log.event(kind, **fields)
        self.notes.clear()

    def write(self, log: RunLog) -> None:
        """The tick's `llm_call`, `guard` and `suggestion` events, once its command is out."""
        for item in self.outbox:
            kind, fields = item() if callable(item) else item
            log.event(kind, **fields)
        self.outbox.clear()

    def close(self) -> None:
        """Stop the worker, if any."""
        if self.worker is not None:
            self.worker.close()

    # --- machinery ----------------------------------------------------------------------------------
    def _degrade(self, cause: str) -> None:
        """The worker died: the episode goes on with the baseline alone, and says so.

        A `degraded` event names the cause and marks the run's condition `assist=llm (failed)`, so no
        table pools it with runs the model assisted.
        """
        self.stats.assist_failed = cause
        mark = {"assist": f"{self.ctx.options.assist} (failed)"}
        self.notes.append(("degraded", {"component": "assist", "cause": cause, "condition": mark}))

    def _judge(self, text: str | None) -> Judged | None:
        return None if text is None else judge(text, self.box, self.sent)

    def _record(self, request: ChatRequest, result: ChatResult | None, error: str | None) -> None:
        """The model process's call, logged as `call_model` logs one."""
        caching = bool(self.ctx.backend and self.ctx.backend.caching)
        self.outbox.append(("llm_call", llm_call_fields(request, "suggestion", None, result, error, caching)))

    def _call_virtual(self, request: ChatRequest, now: float) -> Suggestion:
        """Call between ticks with the simulation frozen; charge the latency to simulation time."""
        started = time.perf_counter()
        fixed = self.ctx.options.model_latency
        fixed_s = fixed / 1000.0 if isinstance(fixed, float | int) else None
        try:
            result = call_model(self.ctx, request, purpose="suggestion", step=None)
        except LlmnavError as err:
            latency = fixed_s if fixed_s is not None else time.perf_counter() - started
            return Suggestion(now, now + latency, None, latency, str(err))
        # `measured` and `recorded`: the backend's own figure (a live call's wall time; a replay's record),
        # as the log keeps it, so that a strict replay charges exactly what the original run charged.
        latency = fixed_s if fixed_s is not None else result.logged_latency_s
        return Suggestion(now, now + latency, result.text, latency, None, self._judge(result.text))

    def _adapt_ttl(self) -> None:
        proposed = adaptive_ttl_ms(self.stats.model_latency_ms)
        if proposed is not None and abs(proposed / 1000.0 - self.ttl_s) > TTL_AUTO_STEP * self.ttl_s:
            self.notes.append(
                (
                    "planner",
                    {
                        "kind": "ttl",
                        "ttl_ms": round(proposed, 1),
                        "previous_ms": round(self.ttl_s * 1000.0, 1),
                        "samples": len(self.stats.model_latency_ms),
                    },
                )
            )
            self.ttl_s = proposed / 1000.0


def _suggestion_event(delivered: Suggestion, now: float, found: Verdict, detail: str) -> Event:
    return (
        "planner",
        {
            "kind": "suggestion",
            "stamp": round(delivered.stamp, 4),
            "t_recv": round(now, 4),
            "latency_ms": round(delivered.latency_s * 1000, 2),
            "raw": (delivered.text or "")[:300],
            "verdict": found,
            "detail": detail,
        },
    )
