"""Stepwise multimodal planner (source A): one discrete action per model turn, guarded and vetoed.

Loop, per step (at most `max_iterations`):
1. observe (LiDAR sector text, camera image, detections, per `--sensing`);
2. ask the model with the system prompt of the chosen variant, the history window and the new user turn
   (the first turn carries the task; when the window no longer holds it, the current turn restates it);
3. guard: parse + schema + bounds; a rejection goes back to the model with the exact error
   (at most `max_corrections` correction turns per step, then abort);
4. self-check (optional): the model answers CONFIRMED or a revised JSON, which is guarded again;
5. safety veto on FRONT and BACK: the robot's swept corridor (its width plus a margin) against the scan;
   a blocked motion is described to the model, which must propose another (at most `max_vetoes` per
   step, then abort);
6. execute with the motion layer, log the action, show the step.
Ends on COMPLETE (completed), after `max_iterations` steps (failed), or on abort.

History: an exchange is one step's user turn and the model's accepted answer; `--history all` re-sends
every exchange (with its image), `0` none, `k` the last k. Correction, veto and self-check turns live only
within their step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar

from llmnav.core.chat import ChatRequest, Message
from llmnav.core.declarations import Declarations
from llmnav.guard.ask import GuardedAnswer, ask_guarded
from llmnav.guard.legs import Action
from llmnav.guard.schemas import response_schema
from llmnav.guard.veto import VetoResult, veto_message
from llmnav.planners import prompting
from llmnav.planners.base import MODEL_OPTIONS, EpisodeContext, EpisodeOutcome, Information, Outcome, Planner, StepInfo
from llmnav.planners.observe import Observation, observe
from llmnav.planners.stepwise.answers import ActionBounds, ActionCommand, StepAction
from llmnav.planners.stepwise.options import StepwiseOptions
from llmnav.planners.stepwise.oracle import StepwiseAnswerKey

if TYPE_CHECKING:
    from llmnav.core.chat import AnswerKey
    from llmnav.planners.base import GroundTruth
    from llmnav.sim.motion import MotionResult

SELF_CHECK_TEMPLATE = "self_check"
CONFIRMED = "CONFIRMED"


class _Abort(Exception):
    """The step could not produce a usable, safe action within its bounds."""


@dataclass
class _StepState:
    """What one step accumulated: the turn's messages, retries and model time."""

    turn: list[Message]
    corrections: int = 0
    vetoes: int = 0
    latency_s: float = 0.0


@dataclass
class _Counters:
    """Episode totals reported in the summary's planner metrics."""

    corrections: int = 0
    vetoes: int = 0
    self_checks: int = 0
    revisions: int = 0  # self-checks that revised the answer
    collisions: int = 0


class StepwisePlanner(Planner[StepwiseOptions]):
    """Source A's stepwise planner, with the guard, veto and history done as specified."""

    name: ClassVar[str] = "stepwise"
    needs_backend: ClassVar[bool] = True
    Options: ClassVar[type[StepwiseOptions]] = StepwiseOptions
    declares: ClassVar[Declarations] = Declarations(asks_model_every_decision=True)
    options: ClassVar[frozenset[str]] = MODEL_OPTIONS | {
        "sensing",
        "lidar_sectors",
        "lidar_fov_deg",
        "max_iterations",
        "image_width",
        "image_height",
    }
    information_modes: ClassVar[tuple[Information, ...]] = ("sensed",)  # camera and LiDAR; never a position
    grid_factors: ClassVar[tuple[str, ...]] = ("sensing", "lidar_sectors", "prompt", "history", "self_check")
    condition_keys: ClassVar[tuple[str, ...]] = grid_factors

    def templates(self, options: StepwiseOptions) -> list[str]:
        """Prompt templates this episode uses (their hashes go into the config line)."""
        return [options.prompt, *([SELF_CHECK_TEMPLATE] if _self_check_on(options) else [])]

    def run(self, ctx: EpisodeContext[StepwiseOptions]) -> EpisodeOutcome:
        """Drive one episode; see the module docstring."""
        return _Episode(ctx).run()

    def oracle_answers(self, truth: GroundTruth, options: StepwiseOptions) -> AnswerKey:
        """The action a perfect model would choose at each step (`llmnav.planners.stepwise.oracle`)."""
        return StepwiseAnswerKey(truth, options.max_step_m)


def _self_check_on(options: StepwiseOptions) -> bool:
    return options.self_check or options.prompt == "self-check"


def history_window(exchanges: list[tuple[Message, Message]], history: str) -> list[Message]:
    """The previous exchanges re-sent under `--history` (all, or the last 0/1/2)."""
    if history == "all":
        kept = exchanges
    else:
        k = int(history)
        kept = exchanges[-k:] if k else []  # exchanges[-0:] would be all of them
    return [m for pair in kept for m in pair]


def _task_in_window(n_exchanges: int, history: str) -> bool:
    """Whether the first exchange (the one naming the task) is still re-sent."""
    return n_exchanges > 0 and (history == "all" or n_exchanges <= int(history))


def describe_action(action: StepAction) -> str:
    """`FRONT 1.5 m`, `ROTATE_LEFT 30°`, `COMPLETE`."""
    cmd, p = action.action.command, action.action.parameters
    if cmd in (ActionCommand.FRONT, ActionCommand.BACK):
        return f"{cmd.value} {p:g} m"
    if cmd in (ActionCommand.ROTATE_LEFT, ActionCommand.ROTATE_RIGHT):
        return f"{cmd.value} {p:g}°"
    return cmd.value


class _Episode:
    """The state of one stepwise episode."""

    def __init__(self, ctx: EpisodeContext[StepwiseOptions]) -> None:
        self.ctx = ctx
        self.options = ctx.options
        self.bounds = ActionBounds(max_step_m=self.options.max_step_m)
        self.schema = response_schema(StepAction)
        sensing = set(self.options.sensing)
        self.system = Message(
            "system",
            prompting.render(
                self.options.prompt,
                max_step_m=self.options.max_step_m,
                lidar="lidar" in sensing,
                image="image" in sensing,
                detections="detections" in sensing,
                lidar_sectors=self.options.lidar_sectors,
                lidar_fov_deg=self.options.lidar_fov_deg,
            ),
        )
        self.self_check_text = prompting.render(SELF_CHECK_TEMPLATE) if _self_check_on(self.options) else None
        self.counters = _Counters()
        self.exchanges: list[tuple[Message, Message]] = []  # (user turn, accepted answer) per past step
        self.feedback = ""  # what went wrong with the last action, told with the next observation

    # --- the loop ---------------------------------------------------------------------------------
    def run(self) -> EpisodeOutcome:
        ctx, options = self.ctx, self.options
        step = 0
        try:
            while step < options.max_iterations:
                step += 1
                obs = observe(ctx.world, options, ctx.log, step)
                state = _StepState([obs.message(self._preface())])
                answer, text = self._decide(step, obs, state)
                self.exchanges.append((state.turn[0], Message("assistant", text)))
                if answer.action.command is ActionCommand.COMPLETE:
                    self._log_action(step, answer, None)
                    self._show(step, answer, obs, state)
                    return self._outcome("completed", "the model reported COMPLETE", step)
                result = self._execute(answer)
                self._log_action(step, answer, result)
                self._show(step, answer, obs, state)
        except _Abort as err:
            return self._outcome("aborted", str(err), step)
        return self._outcome(
            "failed", f"max iterations ({options.max_iterations}) reached without COMPLETE", step
        )

    def _preface(self) -> str:
        """The task line, on the first turn or whenever the history window has dropped it."""
        n = len(self.exchanges)
        parts = []
        if not _task_in_window(n, self.options.history):
            parts.append(f"Task: {self.ctx.task.text}")
        if self.feedback:
            parts.append(self.feedback)
        return "\n".join(parts)

    def _outcome(self, outcome: Outcome, reason: str, step: int) -> EpisodeOutcome:
        c = self.counters
        metrics = {
            "corrections": c.corrections,
            "vetoes": c.vetoes,
            "self_checks": c.self_checks,
            "self_check_revisions": c.revisions,
            "collisions": c.collisions,
        }
        return EpisodeOutcome(outcome, reason, iterations=step, metrics=metrics)

    # --- one decision ---------------------------------------------------------------------------
    def _request(self, state: _StepState, *, constrained: bool = True) -> ChatRequest:
        options = self.options
        return ChatRequest(
            messages=(self.system, *history_window(self.exchanges, options.history), *state.turn),
            json_schema=self.schema if constrained else None,
            temperature=options.temperature,
            max_tokens=options.max_tokens,
            seed=options.seed,
        )

    def _guarded(
        self, step: int, state: _StepState, purpose: str, *, reply: str | None = None
    ) -> tuple[StepAction, str]:
        """Ask (or judge `reply`) through the guard, with the step's remaining correction turns."""
        answer: GuardedAnswer[StepAction] = ask_guarded(
            self.ctx,
            self._request(state),
            StepAction,
            self.bounds,
            self.options.max_corrections - state.corrections,
            step=step,
            purpose=purpose,
            reply=reply,
        )
        state.latency_s += answer.latency_s
        state.corrections += answer.corrections
        self.counters.corrections += answer.corrections
        state.turn += answer.turns
        if answer.value is None:
            raise _Abort(f"no valid action after {state.corrections} correction turns: {answer.result.error}")
        return answer.value, answer.text

    def _decide(self, step: int, obs: Observation, state: _StepState) -> tuple[StepAction, str]:
        """A guarded, self-checked, veto-cleared action and the text it came from."""
        answer, text = self._guarded(step, state, "action")
        if self.self_check_text is not None:
            answer, text = self._self_check(step, state, answer, text)
        while True:
            blocked = self._veto(answer, obs)
            if blocked is None:
                return answer, text
            self.ctx.log.event(
                "guard", step=step, outcome="veto", error=blocked.reason, attempt=state.vetoes + 1
            )
            if state.vetoes >= self.options.max_vetoes:
                tried = f"every proposed motion was blocked ({state.vetoes} vetoes)"
                raise _Abort(f"safety veto: {tried}; last: {blocked.reason}")
            state.vetoes += 1
            self.counters.vetoes += 1
            state.turn += [Message("assistant", text), Message("user", veto_message(blocked))]
            answer, text = self._guarded(step, state, "veto")

    def _self_check(
        self, step: int, state: _StepState, answer: StepAction, text: str
    ) -> tuple[StepAction, str]:
        """Ask the model to confirm its answer; a revised answer goes through the guard again."""
        assert self.self_check_text is not None
        self.counters.self_checks += 1
        state.turn += [Message("assistant", text), Message("user", self.self_check_text)]
        result = self.ctx.chat(self._request(state, constrained=False), "self_check", step)
        state.latency_s += result.latency_s
        reply = result.text
        if CONFIRMED in reply.upper() and "{" not in reply:
            state.turn = state.turn[:-2]  # confirmed: the exchange keeps the original answer only
            return answer, text
        self.counters.revisions += 1
        return self._guarded(step, state, "self_check", reply=reply)

    def _veto(self, answer: StepAction, obs: Observation) -> VetoResult | None:
        """The motion layer's verdict when a FRONT/BACK's swept corridor is not clear, else None.

        Asked before executing so the model can be told and asked again; the layer checks again (on the
        same scan) when the motion is commanded, whatever this planner did.
        """
        cmd, p = answer.action.command, answer.action.parameters
        if cmd not in (ActionCommand.FRONT, ActionCommand.BACK):
            return None
        verdict = self.ctx.world.motion.check_straight(p if cmd is ActionCommand.FRONT else -p, scan=obs.scan)
        return None if verdict.allowed else verdict

    # --- acting ---------------------------------------------------------------------------------
    def _execute(self, answer: StepAction) -> MotionResult:
        motion = self.ctx.world.motion
        cmd, p = answer.action.command, answer.action.parameters
        if cmd is ActionCommand.FRONT:
            result = motion.drive(p)
        elif cmd is ActionCommand.BACK:
            result = motion.drive(-p)
        elif cmd is ActionCommand.ROTATE_LEFT:
            result = motion.rotate(math.radians(p))
        else:
            result = motion.rotate(-math.radians(p))
        self.feedback = ""
        if result.stopped_reason == "monitor":  # something the check before it could not see came close
            self.feedback = (
                f"Your last action ({describe_action(answer)}) was stopped after {result.distance_m:.2f} m: "
                f"{result.veto}."
            )
        elif result.veto is not None:  # cannot happen after _decide's check on the same scan; told if it does
            self.feedback = f"Your last action ({describe_action(answer)}) was not executed: {result.veto}."
        elif result.collided:
            self.counters.collisions += 1
            self.feedback = (
                f"Your last action ({describe_action(answer)}) was stopped after {result.distance_m:.2f} m "
                f"by a collision with {result.collision_with}."
            )
        elif not result.ok:
            self.feedback = (
                f"Your last action ({describe_action(answer)}) stopped early ({result.stopped_reason})."
            )
        return result

    def _log_action(self, step: int, answer: StepAction, result: MotionResult | None) -> None:
        command, parameters = answer.action.command.value, answer.action.parameters
        if result is not None:
            action = Action.of(step, command, parameters, result)
        else:  # COMPLETE: nothing moved
            pose = self.ctx.world.robot.pose()
            action = Action(step, command, parameters, pose, pose, distance_m=0.0, rotated_deg=0.0)
        action.log(self.ctx.log)

    def _show(self, step: int, answer: StepAction, obs: Observation, state: _StepState) -> None:
        self.ctx.view.on_step(
            StepInfo(
                step=step,
                action=describe_action(answer),
                reasoning=answer.reasoning,
                front_m=obs.front_m,
                latency_s=state.latency_s,
                vetoes=state.vetoes,
                json_retries=state.corrections,
            )
        )
