"""A tiny real ablation through llmnav.runs.runner: the oracle planner (no model), 2 episodes on corridor_a."""

from __future__ import annotations

import json
from pathlib import Path

from typer.testing import CliRunner

from llmnav.cli import app


def test_tiny_real_oracle_ablation_and_score(tmp_path: Path) -> None:
    out = tmp_path / "ab"
    args = ["ablate", "--scenario", "corridor_a", "--planner", "oracle", "--tasks", "A5", "--poses", "1",
            "--trials", "2", "--out", str(out)]  # fmt: skip
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["size"] == 2 and manifest["done"] == 2
    for entry in manifest["episodes"]:
        summary = json.loads((out / entry["summary"]).read_text())
        assert summary["planner"] == "oracle" and summary["task_id"] == "A5"
        assert summary["seed"] == entry["seed"] and summary["start_pose_index"] == 1
        assert summary["path_length_m"] > 0 and summary["outcome"] == entry["outcome"]
    assert "Success" in result.output and "2/2 episodes done" in result.output
    # resuming a finished ablation runs nothing and leaves the manifest as it was
    again = CliRunner().invoke(app, args)
    assert again.exit_code == 0, again.output
    assert json.loads((out / "manifest.json").read_text()) == manifest
    scored = CliRunner().invoke(app, ["score", str(out), "--format", "json"])
    assert scored.exit_code == 0, scored.output
    assert '"task": "A5"' in scored.output
