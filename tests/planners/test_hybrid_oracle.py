"""Oracle answers for the hybrid planner: scores and choices a perfect model would give, end to end."""

from __future__ import annotations

import json
from pathlib import Path

from llmnav.core.chat import ChatRequest, Message, ScoreRequest
from llmnav.core.geometry import Pose2D
from llmnav.guard.parse import parse_answer
from llmnav.guard.schemas import response_schema
from llmnav.planners.base import GroundTruth, drive_options
from llmnav.planners.hybrid.answers import hybrid_choice_model
from llmnav.planners.hybrid.oracle import HybridAnswerKey
from llmnav.planners.hybrid.scoring import INTENT_PROMPT
from llmnav.runs.runner import EpisodeSpec, run_episode
from llmnav.sensing.relevance import TARGET_PROMPT
from llmnav.world.scenario import load_scenario

ORIGIN = Pose2D(0.0, 0.0, 0.0)


def _key(task_id: str, pose: Pose2D = ORIGIN) -> HybridAnswerKey:
    scenario = load_scenario("factory")
    return HybridAnswerKey(GroundTruth(scenario, scenario.task(task_id), lambda: pose, lambda: 0.0))


def test_target_names_score_high_and_the_content_free_prompt_is_flat() -> None:
    key = _key("T9")  # "Look for a red cylindrical fire extinguisher": FE, alias "extinguisher"
    task = key.truth.task.text
    names = (" oil barrel", " fire extinguisher", " extinguisher", " table")
    assert key.scores(ScoreRequest(TARGET_PROMPT.format(task=task), names)) == (-20.0, 0.0, 0.0, -20.0)
    assert key.scores(ScoreRequest(TARGET_PROMPT.format(task="N/A"), names)) == (-10.0,) * 4


def test_the_intent_follows_the_task_kind() -> None:
    intents = (" drive to something", " turn around on the spot")
    go, turn = _key("T1"), _key("T6")
    assert go.scores(ScoreRequest(INTENT_PROMPT.format(task=go.truth.task.text), intents)) == (0.0, -20.0)
    assert turn.scores(ScoreRequest(INTENT_PROMPT.format(task=turn.truth.task.text), intents)) == (-20.0, 0.0)


def _menu_request(lines: list[str]) -> ChatRequest:
    numbers = tuple(range(1, len(lines) + 1))
    schema = response_schema(hybrid_choice_model(numbers))
    menu = "\n".join(f"{n}. {t}" for n, t in zip(numbers, lines, strict=True))
    return ChatRequest((Message("system", "..."), Message("user", f"Task: x\nLast: started\n{menu}")), schema)


def test_generated_choices_pass_the_guard_schema_and_pick_the_target() -> None:
    key = _key("T8")  # the pile of dark brown boxes
    lines = [
        "Go to oil barrel, 3 m left",
        "Go to dark brown wooden boxes, 8 m ahead",
        "Turn a full circle to look around",
        "Finish",
    ]
    request = _menu_request(lines)
    text = key.answer(request)
    verdict = parse_answer(text, hybrid_choice_model((1, 2, 3, 4)))  # the guard the planner asks through
    assert verdict.ok and verdict.value is not None and verdict.value.option == 2
    at_target = _menu_request(["Explore, 4 m left", "Finish (at wooden boxes)"])
    assert json.loads(key.answer(at_target))["option"] == 2


def test_with_nothing_known_it_looks_once_then_explores_toward_the_target() -> None:
    # The robot at the origin facing +x; the fire extinguisher lies to the right and ahead (x 9.65, y -7).
    key = _key("T9")
    lines = ["Explore, 5 m left", "Explore, 6 m front-right", "Turn a full circle to look around", "Finish"]
    assert json.loads(key.answer(_menu_request(lines)))["option"] == 3
    assert json.loads(key.answer(_menu_request(lines)))["option"] == 2


def test_the_readme_run_with_oracle_answers_succeeds_and_replays(tmp_path: Path) -> None:
    options = drive_options(planner="hybrid", image_width=160, image_height=120)
    first = run_episode(
        EpisodeSpec(
            scenario="", task_text="Go to room 101", options=options, backend="policy:oracle", out_dir=tmp_path / "a"
        )
    )
    assert first["success"] is True and first["answers"] == "oracle"
    again = run_episode(
        EpisodeSpec(
            scenario="",
            task_text="Go to room 101",
            options=options,
            backend=f"replay:{tmp_path / 'a' / 'run.jsonl'}",
            out_dir=tmp_path / "b",
        )
    )
    assert again["final_pose"] == first["final_pose"] and again["success"] is True
