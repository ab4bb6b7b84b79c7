"""The FSM's own options (source C's knobs), beyond the shared `DriveOptions`.

`ttl` is an input alias: `ttl=auto` adapts the TTL to the observed model latencies (from `ttl_ms`), a
number sets `ttl_ms`. `model_latency` is the latency charged to simulated time: the backend's measured
figure, a replay's recorded one, or a fixed number of milliseconds.
"""

from __future__ import annotations

import math
from typing import Annotated, Any, ClassVar, Literal

from pydantic import Field, field_validator, model_validator

from llmnav.planners.base import CliFlag, DriveOptions


class FsmOptions(DriveOptions):
    """What `-o KEY=VALUE` (or the named flags) may set for the FSM."""

    assist: Literal["none", "ema", "llm"] = Field(
        default="none", description="none | ema (smoothed baseline) | llm (fused model suggestions)"
    )
    alpha: float = Field(default=0.5, ge=0, le=1, description="weight of a fresh model suggestion in the command")
    beta: float = Field(default=0.5, ge=0, le=1, description="EMA weight of the new baseline command")
    ttl_ms: float = Field(default=500.0, gt=0, allow_inf_nan=False, description="[ms] suggestion time to live")
    ttl_auto: bool = Field(default=False, description="adapt the TTL to the observed model latencies")
    model_latency: Literal["measured", "recorded"] | Annotated[float, Field(ge=0, allow_inf_nan=False)] = Field(
        default="measured", description="[ms] latency charged to sim time, or measured | recorded"
    )
    max_ticks: int = Field(default=15000, ge=1, description="[ticks] at 50 Hz before the episode fails")
    input_aliases: ClassVar[frozenset[str]] = frozenset({"ttl"})
    cli_flags: ClassVar[tuple[CliFlag, ...]] = (
        CliFlag("--assist", "assist", "Velocity assist: none | ema | llm.", sweep="factor",
                sweep_help="none, ema, llm (comma-separated)."),
        CliFlag("--model-latency", "model_latency", "Latency charged to sim time: MS | measured | recorded.",
                sweep="fixed"),
        CliFlag("--ttl", "ttl", "Suggestion TTL in ms, or auto.", sweep="fixed", also=("ttl_ms", "ttl_auto")),
    )  # fmt: skip

    @model_validator(mode="before")
    @classmethod
    def _aliases(cls, data: Any) -> Any:
        if not isinstance(data, dict):
            return data
        data = dict(data)
        if "ttl" in data:  # `ttl=auto` or `ttl=MS`
            ttl = data.pop("ttl")
            if isinstance(ttl, str) and ttl.strip().lower() == "auto":
                data["ttl_auto"] = True
            else:
                data["ttl_ms"] = ttl
        return data

    @field_validator("model_latency", mode="before")
    @classmethod
    def _latency(cls, value: Any) -> Any:
        text = str(value).strip().lower()
        if text in ("measured", "recorded"):
            return text
        try:
            number = float(text)
        except ValueError:
            raise ValueError("expected MS (>= 0), measured or recorded") from None
        if not math.isfinite(number) or number < 0:
            raise ValueError("expected MS (>= 0), measured or recorded")
        return number
