"""The tilt planner's answer model: one turn in degrees, inside the bound its own option sets."""

from __future__ import annotations

from pydantic import Field

from llmnav.guard.schemas import Answer, Text

MAX_TURN_DEG = 45.0  # [deg] the largest turn the model may ask for


class TiltAnswer(Answer):
    """How far to turn [deg] (positive: left) and why."""

    turn_deg: float = Field(strict=True, ge=-MAX_TURN_DEG, le=MAX_TURN_DEG)
    reason: Text
