"""The trajectory plot is optional: runs without it stay complete and scorable; ablations skip it by default."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from llmnav.cli import app
from llmnav.planners.base import drive_options
from llmnav.runs.runner import EpisodeSpec, run_episode

SMALL = str(Path(__file__).with_name("small_room.yaml"))


def test_episode_without_plot_is_complete_and_scored(tmp_path: Path) -> None:
    spec = EpisodeSpec(
        scenario=SMALL,
        task_id="T1",
        options=drive_options(planner="oracle"),
        out_dir=tmp_path / "run",
        plots=False,
    )
    summary = run_episode(spec)
    run_dir = tmp_path / "run"
    assert summary["outcome"] == "completed" and summary["trajectory"] is None
    assert not (run_dir / "trajectory.png").exists()
    assert json.loads((run_dir / "summary.json").read_text())["outcome"] == "completed"
    scored = CliRunner().invoke(app, ["score", str(run_dir), "--format", "json"])
    assert scored.exit_code == 0, scored.output
    assert '"task": "T1"' in scored.output


def test_ablation_plots_only_when_asked(tmp_path: Path) -> None:
    base = ["ablate", "--scenario", SMALL, "--planner", "oracle", "--tasks", "T1", "--poses", "1"]
    for flag, expect_png in (([], False), (["--plots"], True)):
        out = tmp_path / ("with" if expect_png else "without")
        result = CliRunner().invoke(app, [*base, "--out", str(out), *flag])
        assert result.exit_code == 0, result.output
        manifest = json.loads((out / "manifest.json").read_text())
        assert manifest["done"] == 1
        pngs = list(out.rglob("trajectory.png"))
        assert len(pngs) == (1 if expect_png else 0)


def test_drive_shows_the_result_before_it_draws(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import llmnav.reporting.live as live
    import llmnav.runs.runner as runner

    order: list[str] = []
    print_result, plot_record = live.print_result, runner.plot_record

    def printed(*args: Any) -> None:
        order.append("result")
        print_result(*args)

    def drawn(*args: Any) -> Path:
        order.append("plot")
        assert (tmp_path / "run" / "summary.json").exists()
        return plot_record(*args)

    monkeypatch.setattr(live, "print_result", printed)
    monkeypatch.setattr(runner, "plot_record", drawn)
    base = ["drive", "--scenario", SMALL, "--task-id", "T1", "--planner", "oracle", "--quiet"]
    result = CliRunner().invoke(app, [*base, "--out", str(tmp_path / "run")])
    assert result.exit_code == 0, result.output
    assert order == ["result", "plot"]
    assert (tmp_path / "run" / "trajectory.png").exists()
    assert f"trajectory: {tmp_path / 'run' / 'trajectory.png'}" in " ".join(result.output.split())

    # An interrupted plot keeps the result shown and the summary written.
    def interrupted(*args: Any) -> Path:
        raise KeyboardInterrupt

    monkeypatch.setattr(runner, "plot_record", interrupted)
    result = CliRunner().invoke(app, [*base, "--out", str(tmp_path / "cut")])
    assert result.exit_code != 0
    assert "completed" in result.output
    assert json.loads((tmp_path / "cut" / "summary.json").read_text())["outcome"] == "completed"
