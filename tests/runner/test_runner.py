"""The episode runner end to end with the oracle baseline: run folder, summary, plot, crashes, CLI codes."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

import llmnav.runs.runner as runs_runner
from llmnav.cli import app
from llmnav.errors import ModelError
from llmnav.planners.base import EpisodeContext, EpisodeOutcome, Planner, drive_options
from llmnav.runs.runlog import read_run
from llmnav.runs.runner import EpisodeSpec, exit_code, run_episode

SMALL = str(Path(__file__).with_name("small_room.yaml"))


def _spec(tmp_path: Path, planner: str = "oracle", **kw: Any) -> EpisodeSpec:
    return EpisodeSpec(
        scenario=SMALL,
        task_id="T1",
        task_text=None,
        start_pose=1,
        options=drive_options(planner=planner, **kw),
        backend="local",
        out_dir=tmp_path / "run",
    )


def test_oracle_episode_writes_a_complete_run_folder(tmp_path: Path) -> None:
    summary = run_episode(_spec(tmp_path))
    run_dir = tmp_path / "run"
    assert summary["outcome"] == "completed" and exit_code(summary) == 0
    assert json.loads((run_dir / "summary.json").read_text())["outcome"] == "completed"
    assert (run_dir / "trajectory.png").stat().st_size > 10_000, summary.get("trajectory_error")
    record = read_run(run_dir)
    assert record.complete and record.torn_lines == 0
    config = record.config
    assert config["scenario"] == "small_room" and len(config["scenario_hash"]) == 16
    assert config["task"] == {
        "id": "T1",
        "text": "Go to the red box",
        "kind": "target",
        "difficulty": "medium",
        "targets": [{"object": "RB"}],
        "wording": "bundled",
    }
    assert config["information"] == "oracle" and summary["information"] == "oracle"
    assert config["start_pose_index"] == 1 and config["start_pose"] == [1.5, 3.0, 0.0]
    assert config["backend"] is None  # the oracle needs no model: none is created
    assert config["options"] == drive_options(planner="oracle").model_dump(mode="json")
    assert set(config["versions"]) == {"llmnav", "python", "pybullet", "numpy"}
    poses = record.poses()
    assert poses[0] == [1.5, 3.0, 0.0] and len(poses) > 10
    end = record.of_type("end")[-1]
    assert end["outcome"] == "completed" and end["t_sim"] > 1.0
    # the path length in the summary is the one of the logged samples, close to the oracle's own
    assert summary["path_length_m"] == pytest.approx(summary["planner_metrics"]["travelled_m"], rel=0.05)


class _Crash(Planner):
    name = "crash"
    needs_backend = False

    def __init__(self, error: BaseException) -> None:
        self.error = error

    def run(self, ctx: EpisodeContext) -> EpisodeOutcome:
        ctx.world.motion.drive(0.3)
        raise self.error


def test_a_planner_bug_leaves_a_valid_log_and_is_reraised(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(runs_runner, "get_planner", lambda name: _Crash(ZeroDivisionError("oops\nmore")))
    with pytest.raises(ZeroDivisionError):
        run_episode(_spec(tmp_path))
    record = read_run(tmp_path / "run")
    end = record.of_type("end")[-1]
    assert end["outcome"] == "aborted" and end["reason"] == "crash: ZeroDivisionError: oops"
    assert json.loads((tmp_path / "run" / "summary.json").read_text())["outcome"] == "aborted"
    assert record.poses()[-1][0] > 1.7  # the samples of the motion before the crash are there


def test_an_llmnav_error_ends_the_episode_aborted_with_its_line(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(
        runs_runner, "get_planner", lambda name: _Crash(ModelError("HTTP 503 after 3 tries"))
    )
    summary = run_episode(_spec(tmp_path))
    assert summary["outcome"] == "aborted" and summary["reason"] == "HTTP 503 after 3 tries"
    assert exit_code(summary) == 4  # the server failed, not the model


def test_drive_command_exit_codes_and_json(tmp_path: Path) -> None:
    runner = CliRunner()
    out = tmp_path / "cli"
    ok = runner.invoke(
        app,
        ["drive", "--scenario", SMALL, "--task-id", "T1", "--planner", "oracle", "--out", str(out), "--json"],
    )
    assert ok.exit_code == 0, ok.output
    summary = json.loads(ok.stdout)
    assert summary["outcome"] == "completed" and summary["run_dir"] == str(out)

    bad = runner.invoke(app, ["drive", "--scenario", SMALL, "--task-id", "T1", "--history", "5"])
    assert bad.exit_code == 2 and "--history" in bad.output and "Traceback" not in bad.output
    for args in (
        ["--task-id", "T7"],
        ["--task-id", "T1", "--start-pose", "9"],
        ["--task-id", "T1", "--obstacle", "x"],
        [],
    ):
        res = runner.invoke(app, ["drive", "--scenario", SMALL, "--planner", "oracle", *args])
        assert res.exit_code == 2, (args, res.output)
        assert len(res.output.strip().splitlines()) == 1, res.output

    # an unknown prompt variant is bad input, found before any model loads or run folder exists
    res = runner.invoke(
        app,
        [
            "drive",
            "--scenario",
            SMALL,
            "--task-id",
            "T1",
            "--planner",
            "stepwise",
            "--prompt",
            "nonsense",
            "--out",
            str(tmp_path / "never"),
        ],
    )
    assert res.exit_code == 2 and "unknown prompt variant 'nonsense'" in res.output
    assert not (tmp_path / "never").exists()
