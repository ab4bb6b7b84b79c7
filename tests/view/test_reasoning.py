"""The reasoning a decision shows is that of the answer the guard accepted, read from its `guard` event; a
log written before the guard logged its value still shows the reasoning parsed again from the reply."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from llmnav.planners.base import drive_options
from llmnav.view.model import build_run_view

from .conftest import SMALL, _drive, step_answer


def _draft_then_answer(tmp_path: Path) -> Path:
    # A fenced JSON draft the action schema rejects, then the fenced answer it accepts: the reply parsed
    # again as any JSON object yields the draft's reasoning; the guard accepted the second block.
    draft = json.dumps({"reasoning": "draft: maybe left?"})
    answer = step_answer("COMPLETE", 0, "final: the box is here")
    return _drive(
        tmp_path, "draft", [f"```json\n{draft}\n```\nThen:\n{answer}"], SMALL, task_id="T1",
        options=drive_options(planner="stepwise", sensing=("lidar",)),
    )  # fmt: skip


def test_a_decision_shows_the_reasoning_of_the_accepted_answer(tmp_path: Path) -> None:
    run = _draft_then_answer(tmp_path)
    (guard,) = [e for e in map(json.loads, (run / "run.jsonl").open()) if e["type"] == "guard"]
    assert guard["outcome"] == "ok" and guard["value"]["reasoning"] == "final: the box is here"
    (step,) = build_run_view(run).steps
    assert step.reasoning == "final: the box is here"


def test_a_log_without_guard_values_falls_back_to_the_reply(tmp_path: Path) -> None:
    run = _draft_then_answer(tmp_path)
    old = tmp_path / "old"
    shutil.copytree(run, old)
    events = [json.loads(line) for line in (old / "run.jsonl").read_text(encoding="utf-8").splitlines()]
    for event in events:
        if event["type"] == "guard":
            del event["value"]
    (old / "run.jsonl").write_text("".join(json.dumps(e) + "\n" for e in events), encoding="utf-8")
    (step,) = build_run_view(old).steps
    assert step.reasoning == "draft: maybe left?"  # what the old reader made of such a reply
