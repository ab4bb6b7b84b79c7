"""The one guarded ask loop: send a request, guard the reply, feed the exact problem back, repeat.

`ask_guarded` is how every planner gets a usable value out of a model:

1. send the request (or take a reply already in hand, e.g. a self-check revision);
2. run the guard on the reply (`parse_answer`: extract -> repair -> schema -> bounds);
3. log ONE `guard` event for this attempt: `step`, `attempt` (1 for the first reply, 2 for the first
   correction, ...), `outcome` (ok | parse | schema | bounds), `error`, `purpose`, and `value`: the
   accepted value as JSON data (None when rejected; readers need not parse the reply again). A value
   longer than MAX_VALUE_CHARS is not logged (`value_chars` says how long it was); the run log redacts
   secrets in it as in every line;
4. when the reply is rejected and corrections are left, append the model's reply and a correction turn
   naming the exact problem to the conversation and go to 1; otherwise stop.

The result says what came of it (`value` is None when every attempt failed); what the caller does then
(abort, fall back to a baseline, fail the plan) is the planner's decision, not the guard's.

The context is anything with `chat(request, purpose, step)` and `event(kind, **fields)` — the planners'
`EpisodeContext` has both; `llmnav plan` passes a small stand-in (`CallContext`) around a bare call.

Adopting it in a planner (the hybrid and FSM loops map one to one):
    answer = ask_guarded(ctx, request, model, bounds, ctx.options.max_corrections, step=step)
    if answer.value is None: ...  # out of corrections: answer.result.error says why
Use `purpose` for the first call's purpose ("action", "choice", "suggestion"); correction calls are logged
with purpose "correction". `feedback` replaces the standard correction message when a planner phrases
its own (the waypoint planner lists every map rule a plan broke).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any, Generic, Protocol, TypeVar, cast

from pydantic_core import PydanticSerializationError, to_jsonable_python

from llmnav.core.chat import ChatRequest, ChatResult, Message
from llmnav.guard.parse import GuardResult, correction_message, parse_answer
from llmnav.guard.schemas import Bounds

T = TypeVar("T")
Feedback = Callable[[GuardResult[Any]], str]  # the correction turn for a rejected reply
OnReply = Callable[[int, str, GuardResult[Any], float], None]  # (attempt, reply text, verdict, latency [s])
# [characters] of JSON: the schemas cap each text field, so an accepted answer is far shorter; a longer one
# (a planner guarding free-form JSON) stays in the reply of its `llm_call` event only.
MAX_VALUE_CHARS = 8_000


class AskContext(Protocol):
    """What `ask_guarded` needs: a logged road to the model and an event sink."""

    def chat(self, request: ChatRequest, purpose: str, step: int | None) -> ChatResult:
        """Send `request` to the model (logged as an `llm_call`)."""
        ...

    def event(self, kind: str, **fields: Any) -> None:
        """Log one event."""
        ...


@dataclass
class CallContext:
    """An `AskContext` around a bare call, for callers without an episode (`llmnav plan`)."""

    call: Callable[[ChatRequest, str], ChatResult]
    on_event: Callable[..., None] | None = None

    def chat(self, request: ChatRequest, purpose: str, step: int | None) -> ChatResult:
        """Forward to the wrapped call."""
        return self.call(request, purpose)

    def event(self, kind: str, **fields: Any) -> None:
        """Forward to `on_event` when given."""
        if self.on_event is not None:
            self.on_event(kind, **fields)


@dataclass
class GuardedAnswer(Generic[T]):
    """What one guarded ask produced."""

    value: T | None  # the validated value; None when every attempt was rejected
    text: str  # the last reply's text (the accepted one when `value` is set)
    result: GuardResult[T]  # the guard's verdict on the last reply
    attempts: int  # replies judged (1 + corrections)
    latency_s: float = 0.0  # [s] model time over every call made here (reported by the backend)
    # The turns appended after the request's messages: (assistant reply, user correction) pairs.
    turns: list[Message] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        """Whether a valid value came out."""
        return self.value is not None

    @property
    def corrections(self) -> int:
        """Correction turns sent (rejected replies that were answered with a correction)."""
        return len(self.turns) // 2


def ask_guarded(
    ctx: AskContext,
    request: ChatRequest,
    model: type[T] | Any,
    bounds: Bounds | None = None,
    max_corrections: int = 3,
    *,
    step: int | None = None,
    purpose: str = "action",
    reply: str | None = None,
    feedback: Feedback | None = None,
    schema: dict[str, Any] | None = None,
    on_reply: OnReply | None = None,
) -> GuardedAnswer[T]:
    """Ask until the guard accepts a reply or `max_corrections` correction turns are spent.

    `model` and `bounds` are what `parse_answer` validates against. `reply`, when given, is a reply to
    `request` obtained already: it is judged first, without a call. `schema` is the JSON Schema quoted
    in correction turns (default: the request's own `json_schema`, else the model's). `on_reply` sees
    every judged reply before its `guard` event is logged. Never raises for a bad reply; a backend
    failure propagates (the runner ends the episode with its message).
    """
    messages = list(request.messages)
    turns: list[Message] = []
    latency = 0.0
    quoted = schema if schema is not None else request.json_schema
    attempt = 0
    while True:
        attempt += 1
        if reply is None:
            sent = replace(request, messages=(*messages, *turns))
            answer = ctx.chat(sent, purpose if attempt == 1 else "correction", step)
            latency += answer.latency_s
            text, took = answer.text, answer.latency_s
        else:
            text, took, reply = reply, 0.0, None
        result: GuardResult[T] = parse_answer(text, model, bounds=bounds)
        if on_reply is not None:
            on_reply(attempt, text, result, took)
        ctx.event(
            "guard",
            step=step,
            attempt=attempt,
            outcome=result.outcome,
            error=result.error,
            purpose=purpose,
            **logged_value(result.value),
        )
        if result.ok or attempt > max_corrections:
            return GuardedAnswer(result.value, text, result, attempt, latency, turns)
        if feedback is not None:
            correction = feedback(result)
        else:
            correction = correction_message(result, quoted if quoted is not None else cast(Any, model))
        turns += [Message("assistant", text), Message("user", correction)]


def logged_value(value: Any) -> dict[str, Any]:
    """The `guard` event's `value` field: the accepted value as JSON data, or None (see the module docstring)."""
    if value is None:
        return {"value": None}
    try:
        data = to_jsonable_python(value)
        chars = len(json.dumps(data, ensure_ascii=False))
    except (PydanticSerializationError, TypeError, ValueError):  # a value type with no JSON form
        return {"value": None}
    return {"value": data} if chars <= MAX_VALUE_CHARS else {"value": None, "value_chars": chars}
