"""Finite-state machine with asynchronous LLM assist (source C: sign-following in a maze).

A deterministic 50 Hz FSM (SEARCH, APPROACH, ACT_LEFT, ACT_RIGHT, ACT_STOP) drives toward traffic signs
seen by the detector. Its baseline command is v = sat(k_v (d - d_goal)), w = sat(k_w e_theta) with
first-order rate limits. With `--assist llm` a model proposes a velocity from a state message published
only in APPROACH; a proposal is used only if well-formed, fresh (t_recv - t_stamp <= TTL) and within the
kinematic bounds, then projected onto the admissible box and fused,
v = (1 - alpha) v_base + alpha * proj(v_llm), and held until a newer one arrives or it expires.
With `--assist ema` the baseline is smoothed instead: v_t = (1 - beta) v_{t-1} + beta v_base.

The model's side is kept small, because its cost is almost all prompt reading and decoding: the state
message is one short line (`stop 1.23 -0.10 45 -150`: class, distance [m] and offset to 2 decimals, the
baseline v [mm/s] and w [mrad/s]; the legend is in the fixed system prompt, served from the prompt
cache), and the answer is `[v, w]` in whole mm/s and mrad/s, whose JSON Schema carries the kinematic
box as minimum/maximum, so a grammar-constrained backend cannot produce an out-of-box value.
The stamp and the deadline stay on the controller's side. A schema the backend cannot compile is
reported before the first tick.

Model latency charged to simulation time (`--model-latency`): what the backend reports for the call
(`measured`, the default: the wall time of a live call, the original run's in a replay), the replay's
recorded latency (`recorded`, a replay backend only), or a fixed number of milliseconds (reproduces,
say, a Jetson's timing on a laptop). `--ttl auto` sets the TTL from the latencies seen so far
(p95 x 1.2, within [TTL_AUTO_MIN_MS, TTL_AUTO_MAX_MS]) and logs each change.

The loop never waits for the model. Two timing modes:
- virtual (default): simulation time is the only clock. The model is called between ticks while the
  simulation is frozen, and its measured latency is charged to simulation time before the answer can be
  used, so the run is deterministic for a deterministic backend (replay returns the recorded latency).
- realtime (`--realtime`): ticks are paced to the wall clock and the model runs in a worker thread, or,
  when it computes inside this process (the local backend), in a process of its own that the loop
  thread polls between ticks, so the loop never waits for the GIL (llmnav.backends.isolated); answers
  are used at the tick after they arrive.
Tick latency is the controller's own work (tick start -> command published); physics stepping and the
detector (a separate perception node at `perception_hz`) are the world, not the controller.
"""

from __future__ import annotations

import contextlib
import math
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from llmnav.chat import ChatRequest, ChatResult, Message
from llmnav.errors import LlmnavError
from llmnav.planners.base import DriveOptions, EpisodeContext, EpisodeOutcome, Planner, StepInfo
from llmnav.realtime import frozen_heap, realtime_priority

if TYPE_CHECKING:
    from pathlib import Path

    from llmnav.chat import AnswerKey
    from llmnav.guard.parse import GuardResult
    from llmnav.planners.base import GroundTruth
    from llmnav.runlog import RunRecord
    from llmnav.sim.sensors import Detection

State = Literal["SEARCH", "APPROACH", "ACT_LEFT", "ACT_RIGHT", "ACT_STOP"]
ANSWER_MAX_TOKENS = 12  # `[-60,-800]` is 10 tokens with its end token; a margin, no runaway
Verdict = Literal["accepted", "stale", "bounds", "parse", "error"]

TTL_AUTO_FACTOR = 1.2  # `--ttl auto`: TTL = p95 of the observed model latencies x this
TTL_AUTO_MIN_MS = 100.0  # [ms] floor: a suggestion older than this is stale whatever the model's speed
TTL_AUTO_MAX_MS = 2000.0  # [ms] ceiling: 100 ticks; older commands describe a different situation
TTL_AUTO_MIN_SAMPLES = 5  # latencies seen before the TTL adapts (the start value is `ttl_ms`)
TTL_AUTO_STEP = 0.1  # a new TTL is adopted (and logged) when it differs from the current one by > 10 %


@dataclass(frozen=True)
class FsmConfig:
    """Controller constants (source C's structure; values tuned for the burger in `maze_arena`)."""

    tick_hz: float = 50.0  # [Hz] control rate
    perception_hz: float = 10.0  # [Hz] detector rate
    publish_hz: float = 5.0  # [Hz] state-JSON rate in APPROACH (at most one request in flight)
    d_goal: float = 0.45  # [m] distance to a sign at which the FSM acts on it
    k_v: float = 0.3  # [1/s] linear gain
    v_min: float = 0.0  # [m/s] lower edge of the admissible box (the robot never reverses)
    v_max: float = 0.06  # [m/s] the source's top setpoint
    v_approach_min: float = 0.02  # [m/s] APPROACH floor: k_v (d - d_goal) alone fades to 0 before d_goal
    k_w: float = 1.5  # [1/s] angular gain on the bearing error
    w_max: float = 0.8  # [rad/s]
    accel_max: float = 0.1  # [m/s^2] first-order rate limit on v
    ang_accel_max: float = 2.0  # [rad/s^2] rate limit on w
    search_w: float = 0.4  # [rad/s] rotation while searching for a sign
    turn_w: float = 0.6  # [rad/s] rotation while acting on a left/right sign
    turn_angle: float = math.pi / 2  # [rad]
    lost_after_s: float = 1.0  # [s] sign unseen this long in APPROACH -> SEARCH
    search_timeout_s: float = 30.0  # [s] SEARCH without any sign -> failure
    pose_sample_s: float = 0.25  # [s] trajectory sampling
    cmd_sample_s: float = 0.1  # [s] command-profile sampling for the log and the PNG


@dataclass
class Suggestion:
    """A model answer on its way to the controller."""

    stamp: float  # [s] sim time of the state it answers
    ready_at: float  # [s] sim time from which it may be used
    text: str | None  # raw answer (None when the call failed)
    latency_s: float
    error: str | None = None


@dataclass
class HeldSuggestion:
    """An accepted suggestion, sample-and-hold until newer or expired."""

    stamp: float
    v: float
    w: float


@dataclass
class FsmStats:
    """Counters behind the FSM table of `llmnav score`."""

    tick_latency_ms: list[float] = field(default_factory=list)
    model_latency_ms: list[float] = field(default_factory=list)
    suggestions: int = 0
    rejected: dict[str, int] = field(default_factory=lambda: {"stale": 0, "bounds": 0, "parse": 0, "error": 0})
    accepted: int = 0
    ticks_using: int = 0
    missed_deadlines: int = 0
    scheduling: str = "simulated"  # the loop thread's policy under --realtime (llmnav.realtime)
    model_in: str = "loop"  # where the model runs: called between ticks, a worker "thread" or a "process"


def saturate(value: float, low: float, high: float) -> float:
    """Clip to [low, high]."""
    return min(max(value, low), high)


def rate_limit(target: float, previous: float, max_rate: float, dt: float) -> float:
    """First-order rate limit: move from `previous` toward `target` by at most max_rate * dt."""
    step = max_rate * dt
    return previous + saturate(target - previous, -step, step)


def check_suggestion(
    text: str | None,
    stamp: float,
    t_recv: float,
    ttl_s: float,
    cfg: FsmConfig,
    guard: Callable[[str], GuardResult[Any]] | None = None,
) -> tuple[Verdict, tuple[float, float] | None, str]:
    """Judge a model answer: (verdict, (v [m/s], w [rad/s]) if usable, detail).

    Order: parse, freshness, bounds. The answer is `[v, w]` in whole mm/s and mrad/s. `guard` turns the
    text into a value (the episode passes the guarded ask loop, which logs its verdict); default: the
    guard's parser alone.
    """
    from llmnav.guard.parse import parse_answer
    from llmnav.guard.schemas import VelocityMilli

    if text is None:
        return "error", None, "model call failed"
    result = guard(text) if guard is not None else parse_answer(text, VelocityMilli)
    if result.value is None:
        return "parse", None, result.error or result.outcome
    value: VelocityMilli = result.value
    if t_recv - stamp > ttl_s:
        return "stale", None, f"{(t_recv - stamp) * 1000:.0f} ms old > TTL {ttl_s * 1000:.0f} ms"
    v, w = value.v / 1000.0, value.w / 1000.0
    if not (math.isfinite(v) and math.isfinite(w)) or abs(v) > cfg.v_max or abs(w) > cfg.w_max:
        return "bounds", None, f"({v:.3g}, {w:.3g}) outside |v| <= {cfg.v_max}, |w| <= {cfg.w_max}"
    return "accepted", (v, w), ""


def timing_options(model_latency: str | None, ttl: str | None, backend: str | None = None) -> dict[str, Any]:
    """DriveOptions fields from `--model-latency MS|measured|recorded` and `--ttl MS|auto` (None: unset).

    Raises `BadInputError` (one line, exit 2) for a negative or unparseable latency, a TTL that is
    neither a positive number nor `auto`, or `recorded` with a backend that is not a replay.
    """
    from llmnav.errors import BadInputError

    fields: dict[str, Any] = {}
    if model_latency is not None:
        text = model_latency.strip().lower()
        if text in ("measured", "recorded"):
            if text == "recorded" and backend is not None and not backend.lower().startswith("replay:"):
                raise BadInputError("--model-latency recorded needs a replay backend (--backend replay:RUN_DIR)")
            fields["model_latency"] = text
        else:
            fields["model_latency"] = _number(text, "--model-latency", "MS (>= 0), measured or recorded")
            if fields["model_latency"] < 0:
                raise BadInputError(f"--model-latency {model_latency!r}: must be >= 0 ms")
    if ttl is not None:
        text = ttl.strip().lower()
        if text == "auto":
            fields["ttl_auto"] = True
        else:
            fields["ttl_ms"] = _number(text, "--ttl", "MS (> 0) or auto")
            if fields["ttl_ms"] <= 0:
                raise BadInputError(f"--ttl {ttl!r}: must be > 0 ms")
    return fields


def _number(text: str, flag: str, expected: str) -> float:
    from llmnav.errors import BadInputError

    try:
        value = float(text)
    except ValueError:
        raise BadInputError(f"{flag} {text!r}: expected {expected}") from None
    if not math.isfinite(value):
        raise BadInputError(f"{flag} {text!r}: expected {expected}")
    return value


def adaptive_ttl_ms(latencies_ms: list[float]) -> float | None:
    """`--ttl auto`: p95 of the observed latencies x TTL_AUTO_FACTOR, bounded; None while too few."""
    if len(latencies_ms) < TTL_AUTO_MIN_SAMPLES:
        return None
    p95 = float(np.percentile(np.asarray(latencies_ms), 95))
    return saturate(p95 * TTL_AUTO_FACTOR, TTL_AUTO_MIN_MS, TTL_AUTO_MAX_MS)


def state_message(sign: str | None, distance_m: float, offset: float, base_v: float, base_w: float) -> str:
    """The model's state line: class, distance [m], offset, baseline v [mm/s] and w [mrad/s].

    Two decimals for distance and offset (the detector is not better than that); whole milli-units for
    the command, the units of the answer, so the model compares like with like.
    """
    return f"{sign or 'none'} {distance_m:.2f} {offset:+.2f} {round(base_v * 1000)} {round(base_w * 1000)}"


def project(v: float, w: float, cfg: FsmConfig) -> tuple[float, float]:
    """Projection onto the admissible box [v_min, v_max] x [-w_max, w_max]."""
    return saturate(v, cfg.v_min, cfg.v_max), saturate(w, -cfg.w_max, cfg.w_max)


class _Worker:
    """Realtime mode: runs model calls in a thread; the controller only polls."""

    def __init__(self, call: Any) -> None:
        self._call = call
        self._requests: queue.Queue[tuple[float, ChatRequest] | None] = queue.Queue(maxsize=1)
        self.results: queue.Queue[tuple[float, ChatResult | None, str | None, float]] = queue.Queue()
        self._thread = threading.Thread(target=self._run, name="llmnav-fsm-llm", daemon=True)
        self._thread.start()

    def submit(self, stamp: float, request: ChatRequest) -> None:
        self._requests.put_nowait((stamp, request))

    def poll(self) -> tuple[float, ChatResult | None, str | None, float] | None:
        """(stamp, result, error, latency [s]) of the next answer, or None when none has arrived."""
        try:
            return self.results.get_nowait()
        except queue.Empty:
            return None

    def _run(self) -> None:
        while True:
            item = self._requests.get()
            if item is None:
                return
            stamp, request = item
            started = time.perf_counter()
            try:
                self.results.put((stamp, self._call(request), None, time.perf_counter() - started))
            except LlmnavError as err:
                self.results.put((stamp, None, str(err), time.perf_counter() - started))

    def close(self) -> None:
        try:
            self._requests.put_nowait(None)
        except queue.Full:
            pass
        self._thread.join(timeout=0.1)  # a call still running is abandoned (daemon thread)


class _ProcessWorker:
    """Realtime mode with an in-process engine (`Backend.engine_in_process`): the model in its own process.

    It runs below the loop's priority (llmnav.backends.isolated), and the loop thread itself sends the
    request and polls for the answer between ticks. No other thread of the loop's process runs Python, so the
    loop never waits for the GIL; the `llm_call` event goes through `record`.
    """

    def __init__(self, process: Any, record: Callable[[ChatRequest, ChatResult | None, str | None], None]) -> None:
        self._process = process
        self._record = record
        self._sent: tuple[float, ChatRequest] | None = None

    @classmethod
    def start(
        cls,
        backend: Any,
        schema: dict[str, Any],
        warm_up: ChatRequest,
        record: Callable[[ChatRequest, ChatResult | None, str | None], None],
    ) -> _ProcessWorker:
        """Start the model's process, check the answer schema there and prime its prompt cache.

        All before the first tick. `warm_up` (its answer is dropped, unlogged) puts the system prompt in
        the new process's prompt cache, as earlier episodes do for a model kept in this process: measured
        at load 8, the first suggestion of a cold process read 285 prompt tokens in 49-59 s.
        The model runs below the loop: ordinary beside a loop that runs real-time (more niceness would
        only make its answers staler, 3-4 s against 0.9 s at load 7), else MODEL_NICE below it.
        """
        from llmnav.backends.isolated import MODEL_NICE, ModelProcess
        from llmnav.realtime import available_priority

        nice = MODEL_NICE if available_priority() == "normal" else 0
        process = ModelProcess(backend.spec, backend.options, nice=nice)
        try:
            process.check_schema(schema)
            with contextlib.suppress(LlmnavError):  # a model that cannot answer says so at each suggestion
                process.chat(warm_up)
        except BaseException:
            process.close()
            raise
        return cls(process, record)

    def submit(self, stamp: float, request: ChatRequest) -> None:
        self._sent = (stamp, request)
        self._process.submit(request)

    def poll(self) -> tuple[float, ChatResult | None, str | None, float] | None:
        """(stamp, result, error, latency [s]) once the answer is there, else None; never waits."""
        reply = self._process.poll()
        if reply is None or self._sent is None:
            return None
        (stamp, request), self._sent = self._sent, None
        result, error, latency = reply
        message = None if error is None else str(error)
        self._record(request, result, message)
        return stamp, result, message, latency

    def close(self) -> None:
        self._process.close()


class FsmPlanner(Planner):
    """Source C's sign-following FSM, optionally assisted by a model (see module docstring)."""

    name = "fsm"
    needs_backend = True
    options = frozenset(
        {"assist", "alpha", "beta", "ttl_ms", "ttl_auto", "model_latency", "max_ticks", "temperature", "max_tokens"}
    )
    paces_itself = True  # its 50 Hz ticks follow the wall clock under --realtime, not the physics steps

    def __init__(self, config: FsmConfig | None = None) -> None:
        self.cfg = config or FsmConfig()

    @staticmethod
    def templates(options: DriveOptions) -> list[str]:
        """Prompt templates this planner renders (their hashes go into the run config)."""
        return ["fsm_velocity"] if options.assist == "llm" else []

    def requires_backend(self, options: DriveOptions) -> bool:
        """Only `--assist llm` talks to a model."""
        return options.assist == "llm"

    # --- the episode --------------------------------------------------------------------------
    def run(self, ctx: EpisodeContext) -> EpisodeOutcome:
        """Tick the FSM until the stop sign, a collision or the tick budget."""
        cfg, opts, world, log = self.cfg, ctx.options, ctx.world, ctx.log
        dt = 1.0 / cfg.tick_hz
        use_llm = opts.assist == "llm" and ctx.backend is not None
        ttl_s = opts.ttl_ms / 1000.0
        stats = FsmStats()
        system_prompt = self._system_prompt() if use_llm else ""
        schema = self.answer_schema() if use_llm else None
        outbox: list[tuple[str, dict[str, Any]]] = []  # events of a tick, written after its command is out
        worker: _Worker | _ProcessWorker | None = None
        if use_llm and opts.realtime and ctx.backend is not None and ctx.backend.engine_in_process:
            warm_up = self._request(system_prompt, schema or {}, state_message("stop", 1.0, 0.0, 0.0, 0.0), opts)
            worker = self._process_worker(ctx, schema or {}, warm_up, outbox)  # it checks the schema there
            stats.model_in = "process"
        else:
            if ctx.backend is not None and schema is not None:
                ctx.backend.check_schema(schema)  # a grammar that cannot compile ends the episode before tick 0
            if use_llm and opts.realtime:
                worker = _Worker(lambda req: self._call(ctx, req))
                stats.model_in = "thread"

        state: State = "SEARCH"
        consumed: set[str] = set()
        target_id: str | None = None
        last_seen = 0.0
        state_since = 0.0
        turn_start_yaw = 0.0
        turned = 0.0
        detections: list[Detection] = []
        base_v = base_w = out_v = out_w = 0.0
        held: HeldSuggestion | None = None
        raw_v: float | None = None
        raw_w: float | None = None
        pending: Suggestion | None = None
        sent: ChatRequest | None = None  # the request in flight (at most one), for the guard's record
        in_flight = False
        last_publish = -math.inf
        next_pose = next_cmd = next_detect = 0.0
        start_pose = world.robot.pose()
        log.event("pose", pose=start_pose.as_list())
        outcome: EpisodeOutcome | None = None
        if opts.realtime:
            # One-time costs (the renderer's first frame, the guard's imports and schema build) would
            # otherwise land on the first ticks and the first suggestion: pay them before the clock starts.
            world.detector.detect()
            if use_llm:
                from llmnav.observe import call_model  # noqa: F401 - imported by the worker's first call

                check_suggestion("[0,0]", 0.0, 0.0, ttl_s, cfg)
                check_suggestion("```json\n{}\n```", 0.0, 0.0, ttl_s, cfg)

        def log_state(previous: State, new: State) -> None:
            log.event(
                "planner",
                kind="fsm_state",
                previous=previous,
                state=new,
                sign=target_id,
                pose=world.robot.pose().as_list(),
            )

        tick = 0
        # Realtime: the loop thread runs ahead of every ordinary process where permitted, so another job on
        # the same cores cannot make it miss a slot (the model's process or worker thread stays below it).
        scheduling = contextlib.ExitStack()
        stats.scheduling = scheduling.enter_context(realtime_priority()) if opts.realtime else "simulated"
        if opts.realtime:
            scheduling.enter_context(frozen_heap())  # its full collection, too, is paid before the clock starts
        wall_start = time.perf_counter()

        try:
            for tick in range(opts.max_ticks):
                now = world.sim_time
                log.sim_time = now
                # Perception node (outside the controller's budget).
                if now >= next_detect - 1e-9:
                    detections = [d for d in world.detector.detect() if d.sign is not None]
                    next_detect = now + 1.0 / cfg.perception_hz
                if opts.realtime:
                    self._pace(wall_start, tick, dt, stats)

                tick_start = time.perf_counter()
                # --- deliver model answers that are due ------------------------------------------
                if use_llm:
                    if worker is not None and pending is None:
                        pending = self._received(worker, now, opts)
                    delivered = self._due(pending, now)
                    if delivered is not None:
                        pending, in_flight = None, False
                        stats.suggestions += 1
                        stats.model_latency_ms.append(delivered.latency_s * 1000.0)
                        verdict, value, detail = check_suggestion(
                            delivered.text, delivered.stamp, now, ttl_s, cfg, self._guard(ctx, sent, outbox)
                        )
                        if value is not None:
                            stats.accepted += 1
                            held = HeldSuggestion(delivered.stamp, *value)
                        else:
                            stats.rejected[verdict] += 1
                        outbox.append(
                            (
                                "planner",
                                {
                                    "kind": "suggestion",
                                    "stamp": round(delivered.stamp, 4),
                                    "t_recv": round(now, 4),
                                    "latency_ms": round(delivered.latency_s * 1000, 2),
                                    "raw": (delivered.text or "")[:300],
                                    "verdict": verdict,
                                    "detail": detail,
                                },
                            )
                        )
                        if opts.ttl_auto:
                            proposed = adaptive_ttl_ms(stats.model_latency_ms)
                            if proposed is not None and abs(proposed / 1000.0 - ttl_s) > TTL_AUTO_STEP * ttl_s:
                                log.event(
                                    "planner",
                                    kind="ttl",
                                    ttl_ms=round(proposed, 1),
                                    previous_ms=round(ttl_s * 1000.0, 1),
                                    samples=len(stats.model_latency_ms),
                                )
                                ttl_s = proposed / 1000.0
                    if held is not None and now - held.stamp > ttl_s:
                        held = None  # expired: the baseline applies at once

                # --- FSM ------------------------------------------------------------------------
                visible = {d.object_id: d for d in detections if d.object_id not in consumed}
                previous_state = state
                if state == "SEARCH":
                    if visible:
                        target_id = min(visible.values(), key=lambda d: d.distance_m).object_id
                        state, last_seen = "APPROACH", now
                    elif now - state_since > cfg.search_timeout_s:
                        outcome = EpisodeOutcome("failed", "no sign found while searching", tick)
                        break
                if state == "APPROACH":
                    seen = visible.get(target_id or "")
                    if seen is not None:
                        last_seen = now
                        if seen.distance_m <= cfg.d_goal:
                            state = {"left": "ACT_LEFT", "right": "ACT_RIGHT"}.get(seen.sign or "", "ACT_STOP")  # type: ignore[assignment]
                    elif now - last_seen > cfg.lost_after_s:
                        state = "SEARCH"
                if state != previous_state:
                    state_since = now
                    turn_start_yaw, turned = world.robot.odom().yaw, 0.0
                    if previous_state == "APPROACH" and state != "SEARCH":
                        consumed.add(target_id or "")
                    if state != "APPROACH":
                        held = None
                        if worker is None:  # a worker's answer still arrives and is judged (likely stale)
                            pending, in_flight = None, False
                    log_state(previous_state, state)

                # --- baseline command -------------------------------------------------------------
                target_v, target_w = 0.0, 0.0
                if state == "SEARCH":
                    target_w = cfg.search_w
                elif state == "APPROACH" and target_id in visible:
                    seen = visible[target_id]
                    target_v = saturate(cfg.k_v * (seen.distance_m - cfg.d_goal), cfg.v_approach_min, cfg.v_max)
                    target_w = saturate(cfg.k_w * math.radians(seen.bearing_deg), -cfg.w_max, cfg.w_max)
                elif state in ("ACT_LEFT", "ACT_RIGHT"):
                    yaw = world.robot.odom().yaw
                    turned += abs(math.remainder(yaw - turn_start_yaw, math.tau))
                    turn_start_yaw = yaw
                    if turned >= cfg.turn_angle:
                        log_state(state, "SEARCH")
                        state, state_since = "SEARCH", now
                    else:
                        target_w = cfg.turn_w if state == "ACT_LEFT" else -cfg.turn_w
                base_v = rate_limit(target_v, base_v, cfg.accel_max, dt)
                base_w = rate_limit(target_w, base_w, cfg.ang_accel_max, dt)

                # --- fusion / smoothing -------------------------------------------------------------
                raw_v = raw_w = None
                if state == "ACT_STOP":
                    cmd_v = cmd_w = 0.0
                elif opts.assist == "ema":
                    cmd_v = (1 - opts.beta) * out_v + opts.beta * base_v
                    cmd_w = (1 - opts.beta) * out_w + opts.beta * base_w
                elif held is not None and state == "APPROACH":
                    raw_v, raw_w = held.v, held.w
                    proj_v, proj_w = project(held.v, held.w, cfg)
                    cmd_v = (1 - opts.alpha) * base_v + opts.alpha * proj_v
                    cmd_w = (1 - opts.alpha) * base_w + opts.alpha * proj_w
                    stats.ticks_using += 1
                else:
                    cmd_v, cmd_w = base_v, base_w
                out_v, out_w = cmd_v, cmd_w
                stats.tick_latency_ms.append((time.perf_counter() - tick_start) * 1000.0)  # published
                for kind, fields in outbox:  # the suggestion's guard verdict and its record, after publishing
                    log.event(kind, **fields)
                outbox.clear()

                # --- publish the state JSON (APPROACH only, one request in flight) ------------------
                if (
                    use_llm
                    and state == "APPROACH"
                    and not in_flight
                    and target_id in visible
                    and now - last_publish >= 1.0 / cfg.publish_hz - 1e-9
                ):
                    seen = visible[target_id]
                    assert schema is not None
                    text = state_message(seen.sign, seen.distance_m, seen.offset, base_v, base_w)
                    request = sent = self._request(system_prompt, schema, text, opts)
                    last_publish, in_flight = now, True
                    if worker is not None:
                        worker.submit(now, request)
                    else:
                        pending = self._call_virtual(ctx, request, now)

                # --- world -------------------------------------------------------------------------
                if now >= next_cmd - 1e-9:
                    log.event(
                        "planner",
                        kind="cmd",
                        state=state,
                        base=[round(base_v, 4), round(base_w, 4)],
                        raw=None if raw_v is None else [round(raw_v, 4), round(raw_w or 0.0, 4)],
                        fused=[round(cmd_v, 4), round(cmd_w, 4)],
                    )
                    next_cmd = now + cfg.cmd_sample_s
                if state == "ACT_STOP":
                    outcome = EpisodeOutcome("completed", "stopped at the stop sign", tick + 1)
                    break
                result = world.motion.velocity_tick(cmd_v, cmd_w, dt)
                if now >= next_pose - 1e-9:
                    log.event("pose", pose=world.robot.pose().as_list())
                    next_pose = now + cfg.pose_sample_s
                if result.collided:
                    outcome = EpisodeOutcome(
                        "failed", f"collided with {result.collision_with or 'an obstacle'}", tick + 1
                    )
                    break
                if tick % 25 == 0:
                    ctx.view.on_step(StepInfo(step=tick, action=f"{state} v={cmd_v:.3f} w={cmd_w:.2f}"))
        finally:
            scheduling.close()  # ordinary priority again before the episode's bookkeeping
            for kind, fields in outbox:  # a tick that ended the episode before publishing
                log.event(kind, **fields)
            if worker is not None:
                worker.close()

        if outcome is None:
            outcome = EpisodeOutcome("failed", f"tick budget exhausted ({opts.max_ticks} ticks)", opts.max_ticks)
        final = world.robot.pose()
        log.event("pose", pose=final.as_list())
        outcome.metrics = self._metrics(ctx, stats, final, start_pose)
        outcome.metrics["ttl_ms"] = round(ttl_s * 1000.0, 1)
        return outcome

    # --- helpers ----------------------------------------------------------------------------
    def _pace(self, wall_start: float, tick: int, dt: float, stats: FsmStats) -> None:
        """Realtime: sleep until this tick's slot; count a missed deadline when already past it."""
        slot = wall_start + tick * dt
        lag = time.perf_counter() - slot
        if lag < 0:
            time.sleep(-lag)
        elif lag > dt:
            stats.missed_deadlines += 1

    @staticmethod
    def _process_worker(
        ctx: EpisodeContext,
        schema: dict[str, Any],
        warm_up: ChatRequest,
        outbox: list[tuple[str, dict[str, Any]]],
    ) -> _ProcessWorker:
        """Realtime with an in-process engine: the model in a process of its own, its calls logged via `outbox`."""
        from llmnav.observe import llm_call_fields

        def record(request: ChatRequest, result: ChatResult | None, error: str | None) -> None:
            outbox.append(("llm_call", llm_call_fields(request, "suggestion", None, result, error)))

        return _ProcessWorker.start(ctx.backend, schema, warm_up, record)

    @staticmethod
    def _received(worker: _Worker | _ProcessWorker, now: float, opts: DriveOptions) -> Suggestion | None:
        """Realtime: the next answer from the worker; a fixed `--model-latency` holds it until then."""
        polled = worker.poll()
        if polled is None:
            return None
        stamp, result, error, latency = polled
        if isinstance(opts.model_latency, float | int):  # cannot be faster than reality: a floor
            latency = max(latency, opts.model_latency / 1000.0)
        return Suggestion(stamp, max(now, stamp + latency), result.text if result else None, latency, error)

    @staticmethod
    def _due(pending: Suggestion | None, now: float) -> Suggestion | None:
        if pending is not None and now >= pending.ready_at - 1e-9:
            return pending
        return None

    def answer_schema(self) -> dict[str, Any]:
        """The answer's JSON Schema, with the admissible box as integer bounds in mm/s and mrad/s."""
        from llmnav.guard.schemas import velocity_schema

        return velocity_schema(self.cfg.v_min, self.cfg.v_max, self.cfg.w_max)

    def _system_prompt(self) -> str:
        from llmnav.prompting import render

        cfg = self.cfg
        return render(
            "fsm_velocity",
            v_min=round(cfg.v_min * 1000),
            v_max=round(cfg.v_max * 1000),
            w_max=round(cfg.w_max * 1000),
            d_goal=cfg.d_goal,
        )

    @staticmethod
    def _request(system_prompt: str, schema: dict[str, Any], text: str, opts: DriveOptions) -> ChatRequest:
        return ChatRequest(
            messages=(Message("system", system_prompt), Message("user", text)),
            json_schema=schema,
            temperature=opts.temperature,
            max_tokens=min(opts.max_tokens, ANSWER_MAX_TOKENS),
            seed=opts.seed,
        )

    @staticmethod
    def _guard(
        ctx: EpisodeContext, request: ChatRequest | None, outbox: list[tuple[str, dict[str, Any]]]
    ) -> Callable[[str], GuardResult[Any]]:
        """The guarded ask loop judging a reply already in hand (no correction turns: the loop cannot wait).

        Its `guard` event goes to `outbox`, written once the tick has published its command: writing the
        log is bookkeeping, not part of the control loop's latency.
        """
        from llmnav.guard.ask import CallContext, ask_guarded
        from llmnav.guard.schemas import VelocityMilli

        deferred = CallContext(
            lambda asked, purpose: ctx.chat(asked, purpose, None),
            lambda kind, **fields: outbox.append((kind, fields)),
        )

        def judge(text: str) -> GuardResult[Any]:
            asked = request or ChatRequest(messages=())
            return ask_guarded(deferred, asked, VelocityMilli, None, 0, reply=text, purpose="suggestion").result

        return judge

    @staticmethod
    def _call(ctx: EpisodeContext, request: ChatRequest) -> ChatResult:
        from llmnav.observe import call_model

        return call_model(ctx, request, purpose="suggestion", step=None)

    def _call_virtual(self, ctx: EpisodeContext, request: ChatRequest, now: float) -> Suggestion:
        """Call between ticks with the simulation frozen; charge the latency to simulation time."""
        started = time.perf_counter()
        fixed = ctx.options.model_latency
        fixed_s = fixed / 1000.0 if isinstance(fixed, float | int) else None
        try:
            result = self._call(ctx, request)
        except LlmnavError as err:
            latency = fixed_s if fixed_s is not None else time.perf_counter() - started
            return Suggestion(now, now + latency, None, latency, str(err))
        # `measured` and `recorded`: the backend's own figure (a live call's wall time; a replay's record),
        # as the log keeps it, so that a strict replay charges exactly what the original run charged.
        latency = fixed_s if fixed_s is not None else result.logged_latency_s
        return Suggestion(now, now + latency, result.text, latency)

    def _metrics(self, ctx: EpisodeContext, stats: FsmStats, final: Any, start: Any) -> dict[str, Any]:
        from llmnav.geometry import path_length
        from llmnav.runlog import read_run

        target = self._stop_point(ctx) if ctx.task.targets else None
        e_pos = final.distance_to(*target) if target is not None else None
        poses = read_run(ctx.log.run_dir).poses()
        real = path_length(poses)
        optimal = _shortest_length(ctx, start, target) if target is not None else None
        ticks = max(len(stats.tick_latency_ms), 1)
        lat = np.asarray(stats.tick_latency_ms or [0.0])
        model = np.asarray(stats.model_latency_ms) if stats.model_latency_ms else None
        return {
            "assist": ctx.options.assist,
            "e_pos_m": e_pos,
            "eta": (optimal / real) if optimal and real > 0 else None,
            "optimal_length_m": optimal,
            "real_length_m": real,
            "ticks": len(stats.tick_latency_ms),
            "missed_deadlines": stats.missed_deadlines,
            "scheduling": stats.scheduling,
            "model_in": stats.model_in,
            "tick_latency_ms": {
                "mean": float(lat.mean()),
                "p50": float(np.percentile(lat, 50)),
                "p99": float(np.percentile(lat, 99)),
                "max": float(lat.max()),
            },
            "model_latency_ms": None
            if model is None
            else {
                "mean": float(model.mean()),
                "p50": float(np.percentile(model, 50)),
                "max": float(model.max()),
            },
            "suggestions": stats.suggestions,
            "accepted": stats.accepted,
            "rejected": dict(stats.rejected),
            "r_acc": stats.accepted / stats.suggestions if stats.suggestions else None,
            "r_use": stats.ticks_using / ticks,
        }

    def _stop_point(self, ctx: EpisodeContext) -> tuple[float, float]:
        """p_target of e_pos: where the FSM should stop, d_goal in front of the target sign.

        A target with an explicit goal point (or a point target) is used as it is.
        """
        from llmnav.planners.fsm_oracle import sign_stop_point

        target = ctx.task.targets[0]
        if target.object is None:
            return ctx.scenario.target_points(ctx.task)[0]
        return sign_stop_point(ctx.scenario, ctx.scenario.object(target.object), self.cfg.d_goal)

    def oracle_answers(self, truth: GroundTruth, options: DriveOptions) -> AnswerKey:
        """The velocity a perfect assistant would suggest to each state line (`llmnav.planners.fsm_oracle`)."""
        from llmnav.planners.fsm_oracle import FsmAnswerKey

        return FsmAnswerKey(truth, self.cfg)

    def figures(self, record: RunRecord, out_dir: Path) -> list[Path]:
        """The commanded-velocity profile (`velocity_profile.png`), when plots are on."""
        from llmnav.reporting.velocity import plot_velocity_profile

        path = plot_velocity_profile(out_dir, out_dir / "velocity_profile.png")
        return [] if path is None else [path]


def _shortest_length(ctx: EpisodeContext, start: Any, target: tuple[float, float]) -> float | None:
    """L_opt for the trajectory efficiency: the A* length from the start to the target point."""
    from llmnav.mapping.paths import shortest_path_length

    return shortest_path_length(ctx.scenario, (start.x, start.y), target)
