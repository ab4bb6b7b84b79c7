"""The Gymnasium example agent: a backend drives the factory through the text observation and the guard."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path
from types import ModuleType

import pytest

from llmnav.backends.replay import write_script

EXAMPLE = Path(__file__).parents[2] / "examples" / "gym_llm_agent.py"


def _example() -> ModuleType:
    spec = importlib.util.spec_from_file_location("gym_llm_agent", EXAMPLE)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _answer(command: str, parameters: float) -> str:
    action = {"command": command, "parameters": parameters}
    return json.dumps({"goal": "g", "reasoning": "r", "scene_description": "s", "action": action})


def test_scripted_backend_turns_through_the_guard_and_is_logged(tmp_path: Path) -> None:
    # a malformed answer first: the guard asks again, and the corrected one is executed
    replies = ["not json at all", _answer("ROTATE_LEFT", 180), _answer("ROTATE_LEFT", 185), _answer("COMPLETE", 0)]
    script = write_script(tmp_path / "script", replies)
    code = _example().main(
        ["--backend", f"replay:{script}", "--task-id", "T6", "--max-steps", "5", "--out", str(tmp_path / "runs")]
    )
    assert code == 0
    summary = json.loads((tmp_path / "runs" / "episode-0001" / "summary.json").read_text())
    assert summary["outcome"] == "completed" and summary["task_id"] == "T6"
    assert summary["success"] is True  # 180 + 185 degrees: the full turn
    assert summary["iterations"] == 3


def test_unknown_backend_is_one_line_exit_2(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    assert _example().main(["--backend", "nope", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:")


@pytest.mark.slow
def test_end_to_end_with_the_local_model(tmp_path: Path) -> None:
    code = _example().main(["--task-id", "T6", "--max-steps", "3", "--out", str(tmp_path / "runs")])
    assert code == 0
    summary = json.loads((tmp_path / "runs" / "episode-0001" / "summary.json").read_text())
    assert summary["outcome"] in ("completed", "failed", "aborted")
    assert summary["backend"] == "local"
