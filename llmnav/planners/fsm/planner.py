"""`FsmPlanner`: the episode loop around the controller (`control.tick`) and the model assist (`assist`)."""

from __future__ import annotations

import contextlib
import time
from typing import TYPE_CHECKING, Any, ClassVar

from llmnav.core.realtime import frozen_heap, realtime_priority
from llmnav.errors import BadInputError
from llmnav.planners.base import DriveOptions, EpisodeContext, EpisodeOutcome, Planner, StepInfo
from llmnav.planners.fsm.assist import AssistPipeline, answer_schema, state_message
from llmnav.planners.fsm.control import ControlState, FsmConfig, Fusion, Inputs, Step, tick
from llmnav.planners.fsm.options import FsmOptions
from llmnav.planners.fsm.oracle import FsmAnswerKey
from llmnav.planners.fsm.stats import FsmStats, log_metrics, run_metrics, stop_point
from llmnav.planners.fsm.tables import FSM_DECLARATIONS

if TYPE_CHECKING:
    from llmnav.backends.base import Backend
    from llmnav.core.chat import AnswerKey
    from llmnav.planners.base import GroundTruth
    from llmnav.runs.runlog import RunRecord
    from llmnav.sim.sensors import Detection
    from llmnav.world.scenario import Scenario, Task


class FsmPlanner(Planner):
    """Source C's sign-following FSM, optionally assisted by a model (see `llmnav.planners.fsm`)."""

    name = "fsm"
    needs_backend = True
    Options = FsmOptions
    options = frozenset({"temperature", "max_tokens"})
    grid_factors = ("assist",)
    condition_keys = ("assist",)  # as run: "llm (failed)" when the assist died
    paces_itself = True  # its 50 Hz ticks follow the wall clock under --realtime, not the physics steps
    figure_kinds: ClassVar[tuple[str, ...]] = ("velocity_profile",)  # from its `cmd` records
    declares = FSM_DECLARATIONS

    def __init__(self, config: FsmConfig | None = None) -> None:
        self.cfg = config or FsmConfig()

    @staticmethod
    def templates(options: FsmOptions) -> list[str]:
        """Prompt templates this planner renders (their hashes go into the run config)."""
        return ["fsm_velocity"] if options.assist == "llm" else []

    def requires_backend(self, options: FsmOptions) -> bool:
        """Only `--assist llm` talks to a model."""
        return options.assist == "llm"

    def check_backend(self, backend: Backend, options: FsmOptions) -> None:
        """A recorded latency exists only in a replayed run."""
        if options.model_latency == "recorded" and not backend.spec.lower().startswith("replay:"):
            raise BadInputError("--model-latency recorded needs a replay backend (--backend replay:RUN_DIR)")

    def answer_schema(self) -> dict[str, Any]:
        """The answer's JSON Schema, with the admissible box as integer bounds in mm/s and mrad/s."""
        return answer_schema(self.cfg)

    # --- the episode --------------------------------------------------------------------------
    def run(self, ctx: EpisodeContext) -> EpisodeOutcome:
        """Tick the FSM until the stop sign, a collision or the tick budget."""
        stats = FsmStats()
        assist = self._assist(ctx, stats)
        start = ctx.world.robot.pose()
        ctx.log.event("pose", pose=start.as_list())
        if ctx.options.realtime:
            # One-time costs (the renderer's first frame, the guard's imports and schema build) would
            # otherwise land on the first ticks and the first suggestion: pay them before the clock starts.
            ctx.world.detector.detect()
            if assist is not None:
                assist.warm()
        try:
            outcome = self._loop(ctx, stats, assist)
        finally:
            if assist is not None:
                assist.close()
        final = ctx.world.robot.pose()
        ctx.log.event("pose", pose=final.as_list())
        stop = stop_point(ctx.scenario, ctx.task, self.cfg.d_goal)
        outcome.metrics = run_metrics(stats, ctx.options.assist, final, stop)
        outcome.metrics["ttl_ms"] = round((assist.ttl_s if assist else ctx.options.ttl_ms / 1000.0) * 1000.0, 1)
        if stats.assist_failed is not None:  # the baseline drove on alone: the result must say so
            outcome.reason = f"{outcome.reason}; assist failed: {stats.assist_failed}"
            outcome.metrics["assist_failed"] = stats.assist_failed
        return outcome

    def _assist(self, ctx: EpisodeContext, stats: FsmStats) -> AssistPipeline | None:
        """The model assist of an `--assist llm` episode with a backend, started; None otherwise."""
        if ctx.options.assist != "llm" or ctx.backend is None:
            return None
        assist = AssistPipeline(ctx, self.cfg, stats)
        assist.start()
        return assist

    def _loop(self, ctx: EpisodeContext, stats: FsmStats, assist: AssistPipeline | None) -> EpisodeOutcome:
        """The 50 Hz loop: perception, the tick (its latency measured), then the log and the world."""
        cfg, opts, world, log = self.cfg, ctx.options, ctx.world, ctx.log
        dt = 1.0 / cfg.tick_hz
        fusion = Fusion(opts.assist, opts.alpha, opts.beta)
        control = ControlState()
        detections: tuple[Detection, ...] = ()
        next_pose = next_cmd = next_detect = 0.0
        # Realtime: the loop thread runs ahead of every ordinary process where permitted, so another job on
        # the same cores cannot make it miss a slot (the model's process or worker thread stays below it).
        scheduling = contextlib.ExitStack()
        stats.scheduling = scheduling.enter_context(realtime_priority()) if opts.realtime else "simulated"
        if opts.realtime:
            scheduling.enter_context(frozen_heap())  # its full collection, too, is paid before the clock starts
        wall_start = time.perf_counter()
        try:
            for index in range(opts.max_ticks):
                now = world.sim_time
                log.sim_time = now
                if now >= next_detect - 1e-9:  # the perception node (outside the controller's budget)
                    detections = tuple(d for d in world.detector.detect() if d.sign is not None)
                    next_detect = now + 1.0 / cfg.perception_hz
                if opts.realtime:
                    self._pace(wall_start, index, dt, stats)
                if assist is not None:
                    assist.receive(now)  # a worker's answer, judged by the guard before the tick

                tick_start = time.perf_counter()
                if assist is not None:
                    assist.deliver(now)
                step = tick(cfg, fusion, control, Inputs(now, detections, world.robot.odom().yaw, _held(assist)))
                if step.lost:
                    return EpisodeOutcome("failed", "no sign found while searching", index)
                stats.tick_latency_ms.append((time.perf_counter() - tick_start) * 1000.0)  # published

                control = step.control
                self._after_publish(ctx, step, assist, stats)
                if now >= next_cmd - 1e-9:
                    log.event("planner", kind="cmd", state=control.state, **_cmd_fields(step))
                    next_cmd = now + cfg.cmd_sample_s
                if control.state == "ACT_STOP":
                    return EpisodeOutcome("completed", "stopped at the stop sign", index + 1)
                result = world.motion.velocity_tick(step.v, step.w, dt)
                if now >= next_pose - 1e-9:
                    log.event("pose", pose=world.robot.pose().as_list())
                    next_pose = now + cfg.pose_sample_s
                if result.collided:
                    reason = f"collided with {result.collision_with or 'an obstacle'}"
                    return EpisodeOutcome("failed", reason, index + 1)
                if index % 25 == 0:
                    ctx.view.on_step(StepInfo(step=index, action=f"{control.state} v={step.v:.3f} w={step.w:.2f}"))
        finally:
            scheduling.close()  # ordinary priority again before the episode's bookkeeping
            if assist is not None:  # a tick that ended the episode before publishing
                assist.write_notes(log)
                assist.write(log)
        return EpisodeOutcome("failed", f"tick budget exhausted ({opts.max_ticks} ticks)", opts.max_ticks)

    @staticmethod
    def _after_publish(ctx: EpisodeContext, step: Step, assist: AssistPipeline | None, stats: FsmStats) -> None:
        """The tick's bookkeeping once its command is out: its events, the assist's hold, the next state line."""
        if step.raw is not None:
            stats.ticks_using += 1
        if assist is not None:
            assist.write_notes(ctx.log)
        for previous, state in step.transitions:
            pose = ctx.world.robot.pose().as_list()
            target = step.control.target_id
            ctx.log.event("planner", kind="fsm_state", previous=previous, state=state, sign=target, pose=pose)
        if assist is None:
            return
        if step.drop_suggestion:
            assist.drop()
        assist.write(ctx.log)
        seen, control = step.target, step.control
        if seen is not None:
            line = state_message(seen.sign, seen.distance_m, seen.offset, control.base_v, control.base_w)
            assist.publish(ctx.world.sim_time, line)

    def _pace(self, wall_start: float, tick: int, dt: float, stats: FsmStats) -> None:
        """Realtime: sleep until this tick's slot; count a missed deadline when already past it."""
        slot = wall_start + tick * dt
        lag = time.perf_counter() - slot
        if lag < 0:
            time.sleep(-lag)
        elif lag > dt:
            stats.missed_deadlines += 1

    # --- hooks --------------------------------------------------------------------------------
    def summarize(self, record: RunRecord, scenario: Scenario, task: Task) -> dict[str, Any]:
        """The driven length and eta, from the closed log's pose samples (`stats.log_metrics`)."""
        return log_metrics(record, scenario)

    def oracle_answers(self, truth: GroundTruth, options: DriveOptions) -> AnswerKey:
        """The velocity a perfect assistant would suggest to each state line (`llmnav.planners.fsm.oracle`)."""
        return FsmAnswerKey(truth, self.cfg)


def _held(assist: AssistPipeline | None) -> tuple[float, float] | None:
    return None if assist is None else assist.in_force()


def _cmd_fields(step: Step) -> dict[str, Any]:
    """The sampled `cmd` record: baseline, the model's raw suggestion and the published command."""
    control, raw = step.control, step.raw
    return {
        "base": [round(control.base_v, 4), round(control.base_w, 4)],
        "raw": None if raw is None else [round(raw[0], 4), round(raw[1], 4)],
        "fused": [round(step.v, 4), round(step.w, 4)],
    }
