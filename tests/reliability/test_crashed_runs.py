"""Crashed runs: a run that llmnav crashed under (a bug, not the model nor the server) has no score, is in no
mean and is tabled apart with its cause, where it once kept `"score": 0.0189` and counted in the means,
one of them for the oracle planner. Counted as category "crashed runs".
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from llmnav.baselines.oracle import OraclePlanner
from llmnav.cli import app
from llmnav.planners.base import EpisodeContext, EpisodeOutcome, drive_options
from llmnav.runs.runner import EpisodeSpec, run_episode

CATEGORY = "crashed runs"
SMALL_ROOM = str(Path(__file__).parents[1] / "runner" / "small_room.yaml")


class CrashesAtTheEnd(OraclePlanner):
    """The oracle's drive to the red box, then a bug: the robot ends near the target, the run has no result."""

    def run(self, ctx: EpisodeContext[Any]) -> EpisodeOutcome:
        super().run(ctx)
        raise RuntimeError("a bug after arriving")


def _run(out: Path, planner: OraclePlanner | None = None) -> dict[str, Any]:
    options = drive_options("oracle", seed=0)
    spec = EpisodeSpec(
        scenario=SMALL_ROOM, task_id="T1", options=options, backend="policy:first", out_dir=out, plots=False
    )
    return run_episode(spec, planner_obj=planner)


def test_a_crashed_run_has_no_score_and_is_tabled_apart_with_its_cause(tmp_path: Path, tally: Any) -> None:
    tally.add(CATEGORY, tried=3)
    good = _run(tmp_path / "runs" / "good")
    with pytest.raises(RuntimeError, match="a bug after arriving"):
        _run(tmp_path / "runs" / "crashed", CrashesAtTheEnd())
    summary = json.loads((tmp_path / "runs" / "crashed" / "summary.json").read_text())
    scored = summary["score"] is not None
    tally.add(CATEGORY, failures=int(scored))
    assert summary["outcome"] == "aborted" and not scored and not summary["success"], summary

    result = CliRunner().invoke(app, ["score", str(tmp_path / "runs"), "--format", "json"])
    assert result.exit_code == 0, result.output
    tables = {t["name"]: t for t in json.loads(result.stdout)}
    (episodes,) = tables["episodes"]["records"]
    in_means = episodes["n"] != 1
    tally.add(CATEGORY, failures=int(in_means))
    assert not in_means and episodes["successes"] == int(bool(good["success"])), episodes
    (aborted,) = tables["aborted"]["records"]
    named = aborted["n"] == 1 and aborted["reasons"] == ["crash: RuntimeError: a bug after arriving"]
    tally.add(CATEGORY, failures=int(not named))
    assert named, aborted
    assert "left out of the means: 1 run(s)" in result.stderr and "crash" in result.stderr, result.stderr
