"""The stepwise planner's own options (source A's knobs), beyond the shared `DriveOptions`."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from llmnav.planners.base import DriveOptions


class StepwiseOptions(DriveOptions):
    """What `-o KEY=VALUE` (or the named flags) may set for the stepwise planner."""

    prompt: str = Field(default="full", description="prompt variant: a template name under prompts/")
    history: Literal["all", "0", "1", "2"] = Field(
        default="all", description="[exchanges] previous exchanges re-sent with each step"
    )
    self_check: bool = Field(default=False, description="ask the model to confirm each answer")
    max_vetoes: int = Field(default=3, ge=0, description="[turns] safety-veto negotiation per step")
    max_step_m: float = Field(default=5.0, gt=0, description="[m] upper bound of a FRONT/BACK step")
