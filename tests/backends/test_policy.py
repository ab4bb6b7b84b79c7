"""Null-policy backends: schema-valid answers for every planner's request, seeded, keyword-matched."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from llmnav.backends.base import ChatRequest, Message, get_backend
from llmnav.backends.policy import PolicyBackend
from llmnav.cli import app
from llmnav.errors import BackendSpecError
from llmnav.guard.parse import parse_answer
from llmnav.guard.schemas import response_schema
from llmnav.planners.fsm.answers import VelocitySuggestion
from llmnav.planners.hybrid.answers import hybrid_choice_model
from llmnav.planners.prompting import render
from llmnav.planners.stepwise.answers import StepAction
from llmnav.planners.waypoints.planner.answers import WaypointList, target_choice_model

MENU = [
    "Turn a full circle to look around",
    "Go to room 103, 2 m ahead",
    "Go to window, 10 m ahead",
    "Go to room 105, 4 m front-left",
    "Finish",
]


def hybrid_request(task: str, numbers: tuple[int, ...] = (1, 2, 3, 4, 5)) -> ChatRequest:
    menu = "\n".join(f"{n}. {text}" for n, text in zip(numbers, MENU, strict=True))
    user = render(
        "hybrid_user", task=task, pose="x=0.0 m, y=0.0 m, heading 0°", last_result="-", observation="-", options=menu
    )
    schema = response_schema(hybrid_choice_model(numbers))
    return ChatRequest((Message("system", render("hybrid_system", robot="bot")), Message("user", user)), schema)


def answer(spec: str, request: ChatRequest) -> object:
    return json.loads(get_backend(spec).chat(request).text)


def test_first_takes_the_first_allowed_option():
    assert answer("policy:first", hybrid_request("Go to room 105"))["option"] == 1
    # The first *allowed* value, not the number 1: a menu numbered from 7 gets 7.
    assert answer("policy:first", hybrid_request("Go to room 105", (7, 8, 9, 10, 11)))["option"] == 7


def test_keyword_picks_the_option_sharing_most_words_with_the_task():
    assert answer("policy:keyword", hybrid_request("Go to room 105"))["option"] == 4  # "room" and "105"
    assert answer("policy:keyword", hybrid_request("Drive up to the window please"))["option"] == 3
    # Nothing in common: ties go to the earliest option.
    assert answer("policy:keyword", hybrid_request("Fetch my keys"))["option"] == 1


def test_keyword_reads_the_grounding_listing():
    listing = "- chair_1: office chair at (1.0, 2.0)\n- fire_ext: fire extinguisher at (3.0, 1.0)"
    user = render("ground_user", command="bring the extinguisher here", objects=listing)
    schema = response_schema(target_choice_model(("chair_1", "fire_ext")))
    got = answer("policy:keyword", ChatRequest((Message("user", user),), schema))
    assert got == {"object_id": "fire_ext"}


def test_random_is_seeded_valid_and_not_constant():
    requests = [hybrid_request(f"Go to room {n}") for n in range(100, 140)]
    picks = [answer("policy:random:3", r)["option"] for r in requests]
    assert picks == [answer("policy:random:3", r)["option"] for r in requests]  # same seed, same answers
    assert set(picks) <= {1, 2, 3, 4, 5} and len(set(picks)) >= 3
    assert picks != [answer("policy:random:4", r)["option"] for r in requests]  # another seed, other answers


@pytest.mark.parametrize("policy", ["first", "random:1", "keyword"])
@pytest.mark.parametrize(
    "model",
    [StepAction, WaypointList, VelocitySuggestion, hybrid_choice_model((2, 3)), target_choice_model(("a", "b"))],
    ids=["stepwise", "waypoints", "fsm", "hybrid", "ground"],
)
def test_every_planner_schema_gets_a_guard_valid_answer(policy, model):
    schema = response_schema(model)
    request = ChatRequest((Message("user", "Task: go somewhere"),), schema)
    result = parse_answer(get_backend(f"policy:{policy}").chat(request).text, model)
    assert result.outcome == "ok", result.error


def test_plain_pydantic_schemas_with_refs_are_followed():
    schema = StepAction.model_json_schema()  # keeps "$defs" and "$ref", unlike response_schema
    assert "$defs" in schema
    for spec in ("policy:first", "policy:random:2"):
        result = parse_answer(get_backend(spec).chat(ChatRequest((Message("user", "x"),), schema)).text, StepAction)
        assert result.outcome == "ok", result.error


def test_schema_bounds_are_respected():
    schema = {
        "type": "object",
        "properties": {
            "speed": {"type": "number", "minimum": 2.0, "maximum": 3.0},
            "turn": {"type": "number", "exclusiveMaximum": 0.5},
            "count": {"type": "integer", "minimum": 4, "maximum": 6},
            "half": {"type": "integer", "minimum": 2.5, "maximum": 3.5},
        },
        "required": ["speed", "turn", "count", "half"],
    }
    for spec in ("policy:first", *(f"policy:random:{s}" for s in range(20))):
        got = answer(spec, ChatRequest((Message("user", "x"),), schema))
        assert 2.0 <= got["speed"] <= 3.0 and got["turn"] < 0.5 and 4 <= got["count"] <= 6, (spec, got)
        assert got["half"] == 3, (spec, got)


@pytest.mark.parametrize(
    "spec", ["policy:best", "policy:first:3", "policy:random:x", "policy:random:1.5", "policy:keyword:2"]
)
def test_unknown_policy_is_a_spec_error(spec):
    with pytest.raises(BackendSpecError, match="polic"):
        get_backend(spec)


def test_unknown_policy_on_the_command_line_is_one_line_exit_2(tmp_path):
    result = CliRunner().invoke(
        app, ["drive", "--task", "Go to room 101", "--backend", "policy:best", "--out", str(tmp_path / "r")]
    )
    assert result.exit_code == 2, result.output
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and "unknown policy 'best'" in lines[0], result.output
    assert not (tmp_path / "r").exists()


def test_policy_is_listed_by_llmnav_backends(monkeypatch, closed_port_url):
    monkeypatch.setenv("OLLAMA_HOST", closed_port_url)
    monkeypatch.setenv("OPENAI_BASE_URL", closed_port_url + "/v1")
    monkeypatch.setenv("COLUMNS", "220")
    result = CliRunner().invoke(app, ["backends"])
    assert result.exit_code == 0
    row = next(line for line in result.output.splitlines() if line.startswith("│ policy"))
    assert "policy:first" in row and "yes" in row


def test_spec_round_trips():
    assert PolicyBackend("random:7").spec == "policy:random:7"
    assert get_backend("policy").spec == "policy:first"
    assert not PolicyBackend.multimodal and PolicyBackend.deterministic
