"""Oracle answers for the stepwise planner: `policy:oracle` through the guard, the veto, the log and replay."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from llmnav.backends.policy import PolicyBackend
from llmnav.core.chat import ChatRequest, Message
from llmnav.errors import ModelError
from llmnav.planners.base import Planner, drive_options, planner_class
from llmnav.runs.runner import EpisodeSpec, run_episode

SMALL_IMAGE = {"image_width": 160, "image_height": 120}


def _events(run_dir: Path, kind: str) -> list[dict]:
    lines = (run_dir / "run.jsonl").read_text().splitlines()
    return [e for e in map(json.loads, lines) if e.get("type") == kind]


def _drive(tmp_path: Path, name: str, task: str, pose: int, backend: str = "policy:oracle") -> dict:
    options = drive_options(planner="stepwise", **SMALL_IMAGE)
    spec = EpisodeSpec(
        scenario="factory", task_id=task, start_pose=pose, options=options, backend=backend, out_dir=tmp_path / name
    )
    return run_episode(spec)


def test_oracle_answers_pass_the_guard_and_reach_the_target(tmp_path: Path) -> None:
    summary = _drive(tmp_path, "t1", "T1", 2)
    run = tmp_path / "t1"
    assert summary["outcome"] == "completed" and summary["success"] is True
    assert summary["distance_m"] <= 2.5 and summary["score"] > 0.95
    verdicts = {e["outcome"] for e in _events(run, "guard")}
    assert verdicts == {"ok"}  # no parse, schema or bounds error, and no veto
    assert summary["answers"] == "oracle"
    config = json.loads((run / "run.jsonl").read_text().splitlines()[0])
    assert config["answers"] == "oracle" and config["backend"] == "policy:oracle"


def test_a_full_turn_completes_within_the_score_tolerance(tmp_path: Path) -> None:
    # A fraction of a degree left over used to be asked for again and again (the rotation controller
    # does not carry it out) until the 30-decision cap.
    summary = _drive(tmp_path, "t6", "T6", 1)
    assert summary["outcome"] == "completed" and summary["success"] is True
    assert summary["iterations"] <= 5


def test_the_answers_keep_the_clearance_the_front_veto_demands(tmp_path: Path) -> None:
    # Along the oracle baseline's path (0.10 m beyond the radius) a FRONT was refused beside a shelf: the
    # swept box keeps 0.15 m; T3 from pose 1 ended aborted after three vetoes.
    summary = _drive(tmp_path, "t3", "T3", 1)
    assert summary["success"] is True
    assert summary["safety_vetoes"] == 0


def test_a_strict_replay_of_an_oracle_run_reaches_the_same_pose(tmp_path: Path) -> None:
    first = _drive(tmp_path, "rec", "T8", 3)
    again = _drive(tmp_path, "rep", "T8", 3, backend=f"replay:{tmp_path / 'rec' / 'run.jsonl'}")
    assert again["outcome"] == first["outcome"] == "completed"
    assert again["final_pose"] == first["final_pose"]
    assert again["answers"] == "request"  # a replay reads its recording, not the ground truth


def test_the_oracle_policy_without_an_answer_key_is_a_model_error() -> None:
    backend = PolicyBackend("oracle")
    request = ChatRequest((Message("user", "Task: anything"),), {"type": "object"})
    assert backend.wants_answer_key
    with pytest.raises(ModelError, match="no answer key"):
        backend.chat(request)


def test_every_built_in_model_planner_offers_oracle_answers() -> None:
    for name in ("stepwise", "hybrid"):
        assert planner_class(name).offers_oracle_answers(), name
    assert not Planner.offers_oracle_answers()
