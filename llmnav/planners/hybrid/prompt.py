"""How the hybrid planner gets its decision: an option number under a JSON Schema, or scored options.

(The scored decision's rule is `llmnav.planners.hybrid.scoring`.)

The asked decision shows the task, the last result, the detections (the LiDAR feeds the map and the
veto; its sector table would triple the prompt) and the menu, one short line an option; what the words
mean is said once in the system prompt, which the prompt cache keeps. The schema restricts `option` to
the listed numbers and puts it first, and the answer still passes the guard.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from llmnav.core.chat import ChatRequest, Message
from llmnav.guard.ask import GuardedAnswer, ask_guarded
from llmnav.guard.schemas import response_schema
from llmnav.planners.hybrid.answers import hybrid_choice_model
from llmnav.planners.hybrid.scoring import Candidate
from llmnav.planners.prompting import render

if TYPE_CHECKING:
    from llmnav.planners.base import EpisodeContext
    from llmnav.planners.hybrid.answers import HybridChoice
    from llmnav.planners.hybrid.memory import Memory
    from llmnav.planners.hybrid.menu import Option
    from llmnav.planners.hybrid.scoring import Decision, ScoredChooser
    from llmnav.planners.observe import Observation


def choice_schema(options: list[Option]) -> tuple[Any, dict[str, Any]]:
    """The answer model for this menu and its JSON Schema, with `option` first.

    A small model that rambles in `reasoning` until the token cap has then still chosen, and the guard's
    repair closes the cut-off string.
    """
    model = hybrid_choice_model(tuple(o.number for o in options))
    schema = response_schema(model)
    schema["properties"] = {"option": schema["properties"]["option"]} | {
        k: v for k, v in schema["properties"].items() if k != "option"
    }
    if "required" in schema:
        schema["required"] = ["option", *[k for k in schema["required"] if k != "option"]]
    return model, schema


def sends_image(ctx: EpisodeContext) -> bool:
    """Whether a generated choice's request carries the camera image: only a multimodal backend sees it."""
    return ctx.backend is not None and ctx.backend.multimodal


def ask_choice(
    ctx: EpisodeContext, obs: Observation, options: list[Option], memory: Memory, step: int, max_tokens: int
) -> tuple[int | None, int]:
    """The model's option number through the guard (bounded corrections); (None, errors) on failure."""
    model, schema = choice_schema(options)
    menu = "\n".join(f"{o.number}. {o.text}" for o in options)
    system = render("hybrid_system", robot=ctx.world.robot.spec.name)
    user = render(
        "hybrid_user",
        task=ctx.task.text,
        last_result=memory.last_result,
        observation=f"{obs.detections_text}\n" if obs.detections_text else "",
        options=menu,
    )
    images = (obs.image,) if obs.image is not None and sends_image(ctx) else ()
    request = ChatRequest(
        (Message("system", system), Message("user", user, images)),
        schema,
        ctx.options.temperature,
        min(ctx.options.max_tokens, max_tokens),
        ctx.options.seed,
    )
    answer: GuardedAnswer[HybridChoice] = ask_guarded(
        ctx, request, model, None, ctx.options.max_corrections, step=step, purpose="choice"
    )
    errors = answer.attempts - (1 if answer.ok else 0)
    return (int(answer.value.option) if answer.value is not None else None), errors


def scored_choice(
    ctx: EpisodeContext, chooser: ScoredChooser, options: list[Option], memory: Memory, step: int
) -> Decision:
    """The scored decision on this menu, logged as a `decision` event."""
    candidates = [
        Candidate(
            o.number,
            o.kind,
            (o.name, *o.parts) if o.kind == "landmark" and o.name else (o.near if o.kind == "frontier" else o.at),
            o.distance_m,
            o.utility,
            o.goal if o.kind == "frontier" else o.place,
            o.standing,
        )
        for o in options
    ]
    decision = chooser.choose(candidates, turned=memory.scans > 0, step=step, explored=len(memory.explored))
    ctx.event("decision", step=step, **decision.to_log())
    return decision
