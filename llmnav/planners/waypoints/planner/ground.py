"""Grounding a command in the scenario's object list: exact name first, else the model's scores or its pick."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from llmnav.core.chat import ChatRequest, Message
from llmnav.errors import InvalidActionError
from llmnav.guard.ask import CallContext, GuardedAnswer, ask_guarded
from llmnav.guard.schemas import response_schema
from llmnav.planners.prompting import render
from llmnav.planners.waypoints.planner.answers import target_choice_model
from llmnav.sensing.relevance import most_relevant

if TYPE_CHECKING:
    from collections.abc import Callable

    from llmnav.core.geometry import Point
    from llmnav.planners.waypoints.planner.answers import TargetChoice
    from llmnav.planners.waypoints.planner.plan import ModelCall
    from llmnav.sensing.relevance import Scorer
    from llmnav.world.scenario import LabelledObject, Scenario, Task


def ground_target(
    scenario: Scenario,
    task: Task,
    call: ModelCall,
    max_tries: int = 3,
    *,
    near: Point | None = None,
    tolerance_m: float = 0.05,
    step: int | None = None,
    on_event: Callable[..., None] | None = None,
    score: Scorer | None = None,
) -> LabelledObject:
    """The object a command refers to: exact-name match first, else the model's scores or its pick.

    With `score` (a backend that scores continuations), the candidate whose label the command makes
    likeliest (`llmnav.sensing.relevance`, PMI) is the target, logged as a `grounding` event with every label's
    PMI; without it, the model picks an id from the listed objects.
    `near` (the final waypoint of a plan made already) settles an ambiguous command without a model call
    when exactly one candidate's goal point lies within `tolerance_m` [m] of it. The model's pick goes
    through `ask_guarded` (`max_tries` replies at most); `on_event` receives its `guard` events.
    """
    # deferred: llmnav.world.tasks brings yaml (about 0.02 s), only when a target is grounded
    from llmnav.world.tasks import named_objects

    if task.targets and len(task.targets) == 1 and task.targets[0].object:
        return scenario.object(task.targets[0].object)
    named = named_objects(scenario, task.text)
    if len(named) == 1:
        return named[0]
    candidates = named or list(scenario.objects)
    if near is not None:
        close = [o for o in candidates if math.dist(o.goal_point, near) <= tolerance_m]
        if len(close) == 1:
            return close[0]
    if score is not None:
        labels = list(dict.fromkeys(o.label for o in candidates))
        best, pmi = most_relevant(score, task.text, labels)
        chosen = next(o for o in candidates if o.label == best)
        if on_event is not None:
            rounded = {k: round(v, 3) for k, v in pmi.items()}
            on_event("grounding", step=step, command=task.text, target=chosen.id, pmi=rounded)
        return chosen
    model = target_choice_model(tuple(o.id for o in candidates))
    listing = "\n".join(f"- {o.id}: {o.label} at ({o.goal_point[0]:.1f}, {o.goal_point[1]:.1f})" for o in candidates)
    messages = (
        Message("system", render("ground_system")),
        Message("user", render("ground_user", command=task.text, objects=listing)),
    )
    request = ChatRequest(messages, response_schema(model), 0.0, 64)
    answer: GuardedAnswer[TargetChoice] = ask_guarded(
        CallContext(call, on_event), request, model, None, max_tries - 1, step=step, purpose="ground"
    )
    if answer.value is None:
        raise InvalidActionError(f"the model named no listed object for '{task.text}' after {max_tries} tries")
    return scenario.object(answer.value.object_id)
