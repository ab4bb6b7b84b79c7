"""A generated building drives: the oracle baseline reaches a target in another room in the real simulator."""

from __future__ import annotations

from pathlib import Path

from llmnav.buildings.generate import Request, generate
from llmnav.planners.base import drive_options
from llmnav.runs.runner import EpisodeSpec, run_episode


def test_the_oracle_reaches_a_target_in_a_small_generated_flat(tmp_path: Path) -> None:
    building = generate(Request("flat", 0, rooms=3, size_m=(8.0, 6.0)))
    path = tmp_path / "flat.yaml"
    path.write_text(building.text, encoding="utf-8")
    task = next(t for t in building.scenario.tasks if t.kind == "target")
    spec = EpisodeSpec(
        scenario=str(path),
        task_id=task.id,
        start_pose=1,
        options=drive_options(planner="oracle", seed=0),
        out_dir=tmp_path / "run",
        plots=False,
    )
    summary = run_episode(spec)
    assert summary["outcome"] == "completed" and summary["success"] is True, summary.get("reason")
    assert summary["collisions"] == 0
    assert summary["distance_m"] <= 2.5
    # It drove there: the start lies more than 3 m from the target (check's promise), so the path is long.
    assert summary["path_length_m"] > 1.0
