"""A planner's own score table comes from its declaration: a third-party planner installed by entry point
gets its table from `llmnav score` without any change to llmnav, and a run whose planner is not installed
still gets the common tables, with a note instead of a traceback."""

from __future__ import annotations

import json
import sys
from collections.abc import Callable
from pathlib import Path

import pytest
from typer.testing import CliRunner

sys.path.insert(0, str(Path(__file__).parent))
from score_fakes import config_for, write_run  # noqa: E402

from llmnav.cli import app  # noqa: E402


def _install_turns_planner(install_planner: Callable[[str, str, str], None]) -> None:
    """Register tests/score/turns_planner.py under the planner entry-point group, as `pip install` would."""
    source = (Path(__file__).parent / "turns_planner.py").read_text(encoding="utf-8")
    install_planner("turns", "turns_planner:TurnsPlanner", source)


def _runs(root: Path) -> None:
    for i, (turns, wobble) in enumerate(((2, 1.0), (6, {"mean": 2.0, "max": 5.0}))):
        metrics = {"turns": turns, "dizzy": turns > 3, "wobble": wobble}
        write_run(root / f"turns{i}", config_for("T1", planner="turns"), [[0, 0, 0], [4.0, 0, 0]],
                  metrics=metrics, summary=True)  # fmt: skip
    write_run(root / "ghost", config_for("T1", planner="ghost"), [[0, 0, 0], [4.0, 0, 0]], summary=True)


def test_a_third_party_planner_declares_its_own_score_table(
    tmp_path: Path, install_planner: Callable[[str, str, str], None]
) -> None:
    _install_turns_planner(install_planner)
    _runs(tmp_path / "runs")
    result = CliRunner().invoke(app, ["score", str(tmp_path / "runs"), "--format", "json"])
    assert result.exit_code == 0, result.output
    tables = {t["name"]: t for t in json.loads(result.stdout)}
    turns = tables["turns"]
    assert turns["title"] == "Turning planner (its own table)"
    assert turns["note"] == "declared by the planner, not by llmnav"
    (record,) = turns["records"]  # the uninstalled planner's run is not in it
    assert record["task"] == "T1" and record["n"] == 2 and record["dizzy"] == 1
    assert record["turns"]["mean"] == pytest.approx(4.0)
    assert record["wobble_deg"]["mean"] == pytest.approx(1.5)  # a number, or a distribution's mean
    shown = CliRunner().invoke(app, ["score", str(tmp_path / "runs"), "--table", "turns", "--format", "md"])
    assert shown.exit_code == 0, shown.output
    assert "### Turning planner (its own table)" in shown.stdout
    assert "| Task | Condition | N | Turns | Dizzy | Wobble (deg) |" in shown.stdout
    assert "| T1 | planner=turns | 2 | 4.0 ± 2.8 | 1/2 | 1.500 ± 0.707 |" in shown.stdout


def test_a_run_whose_planner_is_not_installed_gets_the_common_tables(tmp_path: Path) -> None:
    _runs(tmp_path / "runs")  # the turns planner is not installed here either
    result = CliRunner().invoke(app, ["score", str(tmp_path / "runs"), "--format", "json"])
    assert result.exit_code == 0, result.output
    assert "Traceback" not in result.output
    tables = {t["name"]: t for t in json.loads(result.stdout)}
    assert "turns" not in tables
    conditions = {r["condition"] for r in tables["episodes"]["records"]}
    assert conditions == {"planner=ghost", "planner=turns"}
    assert "planner 'ghost' is not installed" in result.stderr
