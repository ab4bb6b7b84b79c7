"""The stepwise planner with the real embedded model (SmolLM2-135M through llama.cpp): the whole loop runs,
every answer goes through the guard, and the episode ends with a summary whatever the tiny model says."""

from __future__ import annotations

from pathlib import Path

import pytest

from llmnav.planners.base import drive_options
from llmnav.runs.runlog import read_run
from llmnav.runs.runner import EpisodeSpec, run_episode

SMALL = str(Path(__file__).parents[1] / "runner" / "small_room.yaml")


@pytest.mark.slow  # measured 93 s at load average 5 and 591 s at 12 on 2 cores (load + 2 decisions)
def test_stepwise_with_the_real_local_model(tmp_path: Path) -> None:
    spec = EpisodeSpec(
        scenario=SMALL,
        task_id="T1",
        task_text=None,
        start_pose=1,
        options=drive_options(
            planner="stepwise", sensing=("lidar",), prompt="short", history="1", max_iterations=2
        ),
        backend="local",
        out_dir=tmp_path / "run",
    )
    summary = run_episode(spec)
    record = read_run(tmp_path / "run")
    assert record.complete and summary["outcome"] in ("completed", "failed", "aborted")
    calls = record.of_type("llm_call")
    assert calls and all("reply" in c for c in calls), [c.get("error") for c in calls]
    assert calls[0]["request"]["json_schema"]["required"] == [
        "goal",
        "reasoning",
        "scene_description",
        "action",
    ]
    assert record.config["backend"] == "local" and summary["llm_calls"] == len(calls)
    assert all(c["reply"]["latency_s"] > 0 for c in calls)
    guards = record.of_type("guard")
    assert guards and {g["outcome"] for g in guards} <= {"ok", "parse", "schema", "bounds", "veto"}
    # every executed command is one the guard accepted: grammar-constrained output never fails to parse
    assert all(g["outcome"] != "parse" for g in guards)
    for action in record.of_type("action"):
        assert action["command"] in ("FRONT", "BACK", "ROTATE_LEFT", "ROTATE_RIGHT", "COMPLETE")
    assert summary["iterations"] <= 2
