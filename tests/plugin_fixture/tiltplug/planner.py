"""The tilt planner: one model answer (its own answer model, its own prompt), one turn, done."""

from __future__ import annotations

import math
from typing import ClassVar

from pydantic import Field

from llmnav.core.chat import ChatRequest, Message
from llmnav.guard.parse import parse_answer
from llmnav.guard.schemas import response_schema
from llmnav.planners.base import CliFlag, DriveOptions, EpisodeContext, EpisodeOutcome, Planner
from tiltplug.answers import MAX_TURN_DEG, TiltAnswer


class TiltOptions(DriveOptions):
    """The tilt planner's own option, with a flag of its own for `drive` and `ablate`."""

    tilt_deg: float = Field(default=10.0, ge=0, le=MAX_TURN_DEG, description="[deg] turn when the model gives none")
    cli_flags: ClassVar[tuple[CliFlag, ...]] = (
        CliFlag("--tilt", "tilt_deg", "Turn in degrees when the model gives none (tilt plug-in).", sweep="factor",
                sweep_help="Turns in degrees (comma-separated; tilt plug-in)."),
    )  # fmt: skip


class TiltPlanner(Planner[TiltOptions]):
    """Asks once how far to turn, turns, and stops."""

    name: ClassVar[str] = "tilt"
    Options: ClassVar[type[TiltOptions]] = TiltOptions
    grid_factors: ClassVar[tuple[str, ...]] = ("tilt_deg",)
    prompt_package: ClassVar[str | None] = "tiltplug"

    def templates(self, options: TiltOptions) -> list[str]:
        return ["tilt_system"]

    def run(self, ctx: EpisodeContext[TiltOptions]) -> EpisodeOutcome:
        system = self.render_prompt("tilt_system", task=ctx.task.text, max_turn_deg=MAX_TURN_DEG)
        request = ChatRequest((Message("system", system), Message("user", "How far?")), response_schema(TiltAnswer))
        reply = ctx.chat(request, "tilt", 1)
        answer = parse_answer(reply.text, TiltAnswer).value
        turn_deg = answer.turn_deg if answer is not None else ctx.options.tilt_deg
        ctx.world.motion.rotate(math.radians(turn_deg))
        ctx.event("tilt", turn_deg=turn_deg, from_model=answer is not None)
        return EpisodeOutcome("completed", "tilted", iterations=1)
