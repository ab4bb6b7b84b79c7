"""The stepwise planner's answer: one discrete action with its parameter, and the bounds the guard holds it to."""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from typing import Any

from pydantic import field_validator

from llmnav.guard.schemas import Answer, Number, Text, shown


class ActionCommand(StrEnum):
    """The stepwise planner's discrete commands (units: FRONT/BACK metres, ROTATE_* degrees)."""

    FRONT = "FRONT"
    BACK = "BACK"
    ROTATE_LEFT = "ROTATE_LEFT"  # counter-clockwise
    ROTATE_RIGHT = "ROTATE_RIGHT"  # clockwise
    COMPLETE = "COMPLETE"


class ActionSpec(Answer):
    """One command and its single numeric parameter ([m] for FRONT/BACK, [deg] for rotations, 0 to finish)."""

    command: ActionCommand
    parameters: Number

    @field_validator("command", mode="before")
    @classmethod
    def _normalise_case(cls, value: object) -> object:
        # Forgive case and surrounding blanks ("front "), but only for pure-ASCII text: a look-alike such
        # as "FRОNT" with a Cyrillic О must stay unknown rather than be "fixed" into a motion.
        if isinstance(value, str) and value.isascii():
            return value.strip().upper()
        return value


class StepAction(Answer):
    """The stepwise planner's answer: what it is after, why, what it sees, and one action."""

    goal: Text
    reasoning: Text
    scene_description: Text
    action: ActionSpec


def step_answer(command: Any, parameters: Any, **fields: Any) -> dict[str, Any]:
    """A stepwise answer as a JSON-able dict: the action plus placeholder texts, any field replaced or added.

    Values are not checked (hostile ones are the point in fuzzing): scripted runs, tests and examples build
    answers with it, and the guard judges them like any model's.
    """
    body: dict[str, Any] = {
        "goal": "reach the target",
        "reasoning": "it looks right",
        "scene_description": "a room",
        "action": {"command": command, "parameters": parameters},
    }
    body.update(fields)
    return body


@dataclass(frozen=True)
class ActionBounds:
    """Ranges of a stepwise action's parameter.

    FRONT/BACK: 0 < metres ≤ `max_step_m`; ROTATE_*: 0 < degrees ≤ `max_rotate_deg`; COMPLETE: exactly 0.
    Decision: COMPLETE with any other number is a bounds error (the prompt says "COMPLETE, 0"), so a model
    that muddles parameters is told so instead of silently passing; the correction turn is cheap.
    """

    max_step_m: float = 5.0  # [m]
    max_rotate_deg: float = 360.0  # [deg]

    def check(self, value: Any) -> str | None:
        """See the class docstring; `value` is a `StepAction` (or its `ActionSpec`)."""
        spec: ActionSpec = value.action if isinstance(value, StepAction) else value
        cmd, p = spec.command, spec.parameters
        if cmd in (ActionCommand.FRONT, ActionCommand.BACK):
            if not 0.0 < p <= self.max_step_m:
                return f"{cmd} takes metres with 0 < parameters <= {self.max_step_m:g}; got {shown(p)}"
        elif cmd in (ActionCommand.ROTATE_LEFT, ActionCommand.ROTATE_RIGHT):
            if not 0.0 < p <= self.max_rotate_deg:
                return f"{cmd} takes degrees with 0 < parameters <= {self.max_rotate_deg:g}; got {shown(p)}"
        elif p != 0.0:
            return f"COMPLETE takes parameters 0; got {p:g}"
        return None
