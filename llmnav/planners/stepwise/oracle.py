"""The stepwise planner's oracle answers: the action a perfect model would choose, from ground truth.

Each answer is re-derived from the robot's true pose, so odometry drift and a motion that stopped short
are corrected on the next step, as a model that saw perfectly would correct them:

- a target task: the shortest collision-free path (`llmnav.mapping.targets.oracle_path`, the oracle
  baseline's path) to the nearest acceptable target's approach band; turn to face its next corner, then
  drive to it (`FRONT`, at most the step bound); within `complete_m` of the target, turn to face it, then
  `COMPLETE`. Moves go exactly to the next corner and turns exactly to its heading: shorter than the
  source's preferred 1 m and 15° only when the corner or heading is that close (precision needs it);
- a rotate or explore task (the 360° turn, "look around"): `ROTATE_LEFT` in 120° parts until the true
  heading has turned a full circle, then `COMPLETE` (parts under 180° keep the turn countable from
  poses read between steps).

When the safety veto refuses an answer, the correction asks again: the next answer halves the distance
(a perfect answer should never be refused; the log keeps every refusal, which is the point of a ceiling).
A self-check question is answered "CONFIRMED".
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from llmnav.core.geometry import wrap_angle
from llmnav.guard.veto import VETO_PREFIX
from llmnav.mapping.grid import GridConfig
from llmnav.mapping.targets import OracleConfig, oracle_path
from llmnav.planners.base import GeneratedAnswers
from llmnav.planners.stepwise.answers import ActionCommand, step_answer

if TYPE_CHECKING:
    from llmnav.core.chat import ChatRequest
    from llmnav.core.geometry import Pose2D
    from llmnav.planners.base import GroundTruth

CONFIRMED = "CONFIRMED"


@dataclass(frozen=True)
class StepwiseOracleConfig:
    """How the oracle's answers are shaped (the source's movement constraints, in its units)."""

    complete_m: float = 2.4  # [m] COMPLETE within this of the target (2.5 m scores fully; keep a margin)
    facing_deg: float = 2.0  # [deg] a heading error below this counts as facing
    turn_part_deg: float = 120.0  # [deg] one part of a full turn
    full_turn_deg: float = 360.0  # [deg] a full turn on the true heading
    turn_slack_deg: float = 5.0  # [deg] a full turn short by less is done: the score takes 350 deg, and a
    # fraction of a degree is below what the rotation controller carries out
    # The path keeps the clearance a FRONT's swept box demands (the motion layer's 0.15 m lateral margin)
    # plus the drift of a 5 m move started 2 deg off: the oracle baseline's 0.10 m is made for go_to legs.
    path: OracleConfig = field(default_factory=lambda: OracleConfig(grid=GridConfig(margin_m=0.3)))


@dataclass
class StepwiseAnswerKey(GeneratedAnswers):
    """The `AnswerKey` of one stepwise episode (see the module docstring)."""

    truth: GroundTruth
    max_step_m: float  # [m] the episode's FRONT/BACK bound
    config: StepwiseOracleConfig = field(default_factory=StepwiseOracleConfig)
    _turned_deg: float = 0.0  # [deg] net true rotation so far (rotate/explore tasks)
    _last_yaw: float | None = None  # [rad] the true heading at the previous answer

    def answer(self, request: ChatRequest) -> str:
        """The JSON answer for the true state now; "CONFIRMED" to a self-check question."""
        if request.json_schema is None:
            return CONFIRMED
        pose = self.truth.pose()
        self._track_turn(pose)
        if self.truth.task.kind != "target":
            command, parameter, why = self._full_turn()
        else:
            command, parameter, why = self._toward_target(pose, _vetoes_in_turn(request))
        body = step_answer(command.value, round(parameter, 3), goal=self.truth.task.text, reasoning=why)
        body["scene_description"] = "oracle answer from ground truth"
        return json.dumps(body)

    def _track_turn(self, pose: Pose2D) -> None:
        if self._last_yaw is not None:
            self._turned_deg += math.degrees(wrap_angle(pose.yaw - self._last_yaw))
        self._last_yaw = pose.yaw

    def _full_turn(self) -> tuple[ActionCommand, float, str]:
        remaining = self.config.full_turn_deg - self._turned_deg
        if remaining <= self.config.turn_slack_deg:
            return ActionCommand.COMPLETE, 0.0, f"turned {self._turned_deg:.0f} degrees"
        return ActionCommand.ROTATE_LEFT, min(self.config.turn_part_deg, remaining), "turning a full circle"

    def _toward_target(self, pose: Pose2D, vetoes: int) -> tuple[ActionCommand, float, str]:
        config = self.config
        path = oracle_path(self.truth.scenario, self.truth.task, pose, config=config.path)
        if path is None:
            return ActionCommand.ROTATE_LEFT, 90.0, "no collision-free path from here; looking for one"
        goal = self.truth.scenario.target_points(self.truth.task)[self.truth.task.targets.index(path.target)]
        if pose.distance_to(*goal) <= config.complete_m:
            error = math.degrees(pose.bearing_to(*path.target_point))
            if abs(error) <= config.facing_deg:
                return ActionCommand.COMPLETE, 0.0, "at the target and facing it"
            return _turn(error, "face the target")
        corner = path.points[1] if len(path.points) > 1 else path.approach
        error = math.degrees(pose.bearing_to(*corner))
        if abs(error) > config.facing_deg:
            return _turn(error, "face the next corner of the shortest path")
        distance = min(pose.distance_to(*corner), self.max_step_m) * 0.5**vetoes
        return ActionCommand.FRONT, max(distance, 0.01), "drive to the next corner of the shortest path"


def _turn(error_deg: float, why: str) -> tuple[ActionCommand, float, str]:
    """A turn by `error_deg` (positive: counter-clockwise), exact: precision needs the last degrees."""
    command = ActionCommand.ROTATE_LEFT if error_deg > 0 else ActionCommand.ROTATE_RIGHT
    return command, abs(error_deg), why


def _vetoes_in_turn(request: ChatRequest) -> int:
    """How many safety vetoes the current step has told (they follow the step's last observation)."""
    count = 0
    for message in reversed(request.messages):
        if message.role != "user":
            continue
        if not message.text.startswith(VETO_PREFIX):
            break
        count += 1
    return count
