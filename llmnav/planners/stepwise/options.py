"""The stepwise planner's own options (source A's knobs), beyond the shared `DriveOptions`."""

from __future__ import annotations

from typing import ClassVar, Literal

from pydantic import Field, field_validator

from llmnav.planners.base import CliFlag, DriveOptions
from llmnav.planners.prompting import stepwise_variants


class StepwiseOptions(DriveOptions):
    """What `-o KEY=VALUE` (or the named flags) may set for the stepwise planner."""

    prompt: str = Field(
        default="full",
        description="prompt variant: full, short, full_noconstraints, short_noconstraints, no_lidar_guidelines "
        "or self-check",
    )
    history: Literal["all", "0", "1", "2"] = Field(
        default="all", description="[exchanges] previous exchanges re-sent with each step"
    )
    self_check: bool = Field(default=False, description="ask the model to confirm each answer")
    max_vetoes: int = Field(default=3, ge=0, description="[turns] safety-veto negotiation per step")
    max_step_m: float = Field(default=5.0, gt=0, description="[m] upper bound of a FRONT/BACK step")
    cli_flags: ClassVar[tuple[CliFlag, ...]] = (
        CliFlag("--prompt", "prompt", "Prompt variant (see prompts/) [default: full].", sweep="factor",
                sweep_help="Prompt variants (comma-separated)."),
        CliFlag("--history", "history", "Previous exchanges re-sent: all | 0 | 1 | 2 [default: all].",
                sweep="factor", sweep_help="0, 1, 2, all (comma-separated)."),
        CliFlag("--self-check", "self_check", "Ask the model to confirm each answer.", switch=True),
    )  # fmt: skip

    @field_validator("prompt")
    @classmethod
    def _one_name(cls, name: str) -> str:
        # One name per variant: another spelling (`self_check`, `full-noconstraints`) once rendered a different
        # text (`self_check` is the follow-up question's template) without a word, so it is refused instead.
        variants = stepwise_variants()
        if name not in variants:
            raise ValueError(f"unknown prompt variant '{name}' (variants: {', '.join(variants)})")
        return name
