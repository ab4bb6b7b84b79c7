"""ask_guarded: one guard event per reply counted from 1, the exact problem fed back, bounded corrections."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from llmnav.core.chat import ChatRequest, ChatResult, Message
from llmnav.guard.ask import MAX_VALUE_CHARS, CallContext, ask_guarded
from llmnav.guard.parse import correction_message, parse_answer
from llmnav.guard.schemas import response_schema
from llmnav.planners.stepwise.answers import ActionBounds, StepAction, step_answer


def step(command: str, parameters: float) -> str:
    return json.dumps(step_answer(command, parameters))


class Scripted:
    """An AskContext answering from a list and recording what it was sent and logged."""

    def __init__(self, replies: list[str]) -> None:
        self.replies = list(replies)
        self.sent: list[tuple[ChatRequest, str, int | None]] = []
        self.events: list[tuple[str, dict[str, Any]]] = []

    def chat(self, request: ChatRequest, purpose: str, step: int | None) -> ChatResult:
        self.sent.append((request, purpose, step))
        return ChatResult(self.replies.pop(0), 0.5, "script")

    def event(self, kind: str, **fields: Any) -> None:
        self.events.append((kind, fields))


REQUEST = ChatRequest((Message("system", "drive"), Message("user", "go")), response_schema(StepAction))
BOUNDS = ActionBounds(max_step_m=5.0)


def test_corrections_quote_the_exact_problem_until_the_answer_is_valid() -> None:
    bad_json, too_far, good = "{not json", step("FRONT", 1e9), step("FRONT", 1.0)
    ctx = Scripted([bad_json, too_far, good])
    answer = ask_guarded(ctx, REQUEST, StepAction, BOUNDS, 3, step=7)
    assert answer.ok and answer.value is not None and answer.value.action.parameters == 1.0
    assert (answer.attempts, answer.corrections, answer.latency_s) == (3, 2, 1.5)
    guards = [f for kind, f in ctx.events if kind == "guard"]
    assert [(g["attempt"], g["outcome"], g["step"]) for g in guards] == [
        (1, "parse", 7),
        (2, "bounds", 7),
        (3, "ok", 7),
    ]
    assert [purpose for _, purpose, _ in ctx.sent] == ["action", "correction", "correction"]
    # the third request carries both rejected replies and, after each, the exact correction
    last = ctx.sent[2][0].messages
    assert [m.role for m in last] == ["system", "user", "assistant", "user", "assistant", "user"]
    expected = correction_message(parse_answer(too_far, StepAction, bounds=BOUNDS), REQUEST.json_schema or {})
    assert last[4].text == too_far and last[5].text == expected and "1e+09" in expected
    assert answer.turns == list(last[2:])


def test_out_of_corrections_returns_the_last_verdict_without_raising() -> None:
    ctx = Scripted(["nope", "still nope"])
    answer = ask_guarded(ctx, REQUEST, StepAction, BOUNDS, 1)
    assert not answer.ok and answer.value is None and answer.result.outcome == "parse"
    assert [f["attempt"] for kind, f in ctx.events if kind == "guard"] == [1, 2]
    assert len(ctx.sent) == 2


def test_a_reply_in_hand_is_judged_first_and_a_custom_feedback_is_used() -> None:
    ctx = Scripted([step("COMPLETE", 0)])
    seen: list[tuple[int, str]] = []
    answer = ask_guarded(
        ctx,
        REQUEST,
        StepAction,
        BOUNDS,
        2,
        reply=step("BACK", -1),
        feedback=lambda result: f"fix: {result.error}",
        on_reply=lambda n, text, result, latency: seen.append((n, result.outcome)),
    )
    assert answer.ok and seen == [(1, "bounds"), (2, "ok")]
    assert len(ctx.sent) == 1 and ctx.sent[0][0].messages[-1].text.startswith("fix: BACK takes metres")


def test_a_bare_call_works_without_an_episode() -> None:
    calls: list[str] = []
    events: list[str] = []

    def call(request: ChatRequest, purpose: str) -> ChatResult:
        calls.append(purpose)
        return ChatResult(step("ROTATE_LEFT", 30), 0.1, "script")

    answer = ask_guarded(CallContext(call, lambda kind, **f: events.append(kind)), REQUEST, StepAction, BOUNDS)
    assert answer.ok and calls == ["action"] and events == ["guard"]


def test_the_guard_event_logs_the_accepted_value_as_json_data() -> None:
    accepted = json.dumps(step_answer("FRONT", 1.0) | {"reasoning": "the corridor is clear"})
    ctx = Scripted(["no JSON here", f"Sure!\n```json\n{accepted}\n```"])
    answer = ask_guarded(ctx, REQUEST, StepAction, BOUNDS, 1, step=2)
    rejected, ok = [f for kind, f in ctx.events if kind == "guard"]
    assert rejected["value"] is None and ok["outcome"] == "ok"
    assert answer.value is not None and ok["value"] == answer.value.model_dump(mode="json")
    assert ok["value"]["reasoning"] == "the corridor is clear" and ok["value"]["action"]["command"] == "FRONT"
    json.dumps(ok["value"])  # plain JSON data, not a model object


def test_a_value_too_long_to_log_is_left_in_the_reply() -> None:
    long = json.dumps({"notes": ["x" * 100] * 100})
    ctx = Scripted([])
    answer = ask_guarded(ctx, REQUEST, dict[str, Any], None, 0, reply=long)
    ((_, event),) = ctx.events
    assert answer.ok and event["value"] is None and event["value_chars"] > MAX_VALUE_CHARS


def test_a_secret_in_the_accepted_value_is_redacted_in_the_run_log(tmp_path: Path) -> None:
    from llmnav.runs.runlog import RunLog, read_run

    key = "sk-test-0123456789"
    with RunLog(tmp_path / "run", {"planner": "stepwise"}, secrets=[key]) as log:
        ctx = CallContext(lambda request, purpose: ChatResult("", 0.0, "script"), log.event)
        reply = json.dumps(step_answer("FRONT", 1.0) | {"reasoning": f"my key is {key}"})
        ask_guarded(ctx, REQUEST, StepAction, BOUNDS, 0, reply=reply)
    (guard,) = read_run(tmp_path / "run").of_type("guard")
    assert guard["value"]["reasoning"] == "my key is ***"
    assert key not in (tmp_path / "run" / "run.jsonl").read_text()
