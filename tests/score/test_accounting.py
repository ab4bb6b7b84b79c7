"""Honest accounting: runs a server outage ended are in no model's mean, a broken run does not cancel the
tables of the rest, and `drive`'s exit code tells success, task failure, model failure and outage apart.

Expected numbers are worked out by hand (tiny scenario: T1's target at (5, 0), full score within 2.5 m).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from typer.testing import CliRunner

sys.path.insert(0, str(Path(__file__).parent))
from score_fakes import config_for, tiny_scenario, write_run  # noqa: E402

from llmnav.cli import app  # noqa: E402
from llmnav.runs.runlog import RUN_FILE, read_run  # noqa: E402
from llmnav.runs.runner import exit_code  # noqa: E402
from llmnav.scoring.metrics import summarize_run  # noqa: E402

AT_TARGET = [[0.0, 0.0, 0.0], [5.0, 0.0, 0.0]]
FAR = [[0.0, 0.0, 0.0], [-4.74, 0.0, 0.0]]  # 9.74 m from the target


def _aborted(run_dir: Path, failure: str, *, summary: bool = True) -> Path:
    """A run whose end event says the backend (or the model) failed; it never moved."""
    write_run(run_dir, config_for("T1"), [[0.0, 0.0, 0.0]], outcome=None)
    with open(run_dir / RUN_FILE, "a") as log:
        end = {"type": "end", "outcome": "aborted", "reason": f"{failure}: HTTP 503", "metrics": {"failure": failure}}
        log.write(json.dumps(end) + "\n")
    return run_dir


def _score(*args: str) -> tuple[list[dict], str]:
    result = CliRunner().invoke(app, ["score", *args, "--format", "json"])
    assert result.exit_code == 0, result.output
    return json.loads(result.stdout), result.stderr


def test_outages_are_listed_apart_and_in_no_mean(tmp_path: Path) -> None:
    write_run(tmp_path / "ok", config_for("T1"), AT_TARGET, summary=True)
    for k in range(3):
        _aborted(tmp_path / f"outage{k}", "backend")
    tables, err = _score(str(tmp_path))
    by_name = {t["name"]: t for t in tables}
    (episodes,) = by_name["episodes"]["records"]
    assert episodes["n"] == 1 and episodes["successes"] == 1  # not "N 4, Success 1/4"
    (aborted,) = by_name["aborted"]["records"]
    assert aborted["n"] == 3 and aborted["reasons"] == ["backend: HTTP 503"]
    assert "3 run(s) aborted by a backend or server failure" in err
    assert "targets could not be resolved" not in err  # an outage has no score by design, not by a fault


def test_a_model_failure_stays_a_result(tmp_path: Path) -> None:
    write_run(tmp_path / "ok", config_for("T1"), AT_TARGET, summary=True)
    _aborted(tmp_path / "invalid", "model")
    tables, err = _score(str(tmp_path))
    (episodes,) = {t["name"]: t for t in tables}["episodes"]["records"]
    assert episodes["n"] == 2 and episodes["successes"] == 1
    assert "aborted" not in {t["name"] for t in tables} and "left out" not in err


def test_an_outage_has_no_score_in_its_summary(tmp_path: Path) -> None:
    summary = summarize_run(read_run(_aborted(tmp_path / "outage", "backend")), tiny_scenario())
    assert summary["score"] is None and summary["success"] is False
    model = summarize_run(read_run(_aborted(tmp_path / "model", "model")), tiny_scenario())
    assert model["score"] is not None  # the model's own failure is scored where it left the robot


def test_one_broken_run_is_skipped_and_named(tmp_path: Path) -> None:
    for k in range(5):
        write_run(tmp_path / f"run{k}", config_for("T1"), AT_TARGET)
    lines = (tmp_path / "run2" / RUN_FILE).read_text().splitlines()
    lines[2] = lines[2][: len(lines[2]) // 2]  # torn in the middle of the log, not at its end
    (tmp_path / "run2" / RUN_FILE).write_text("\n".join(lines) + "\n")
    tables, err = _score(str(tmp_path))
    (episodes,) = {t["name"]: t for t in tables}["episodes"]["records"]
    assert episodes["n"] == 4
    assert "skipped:" in err and "run2" in err and "line 3: not valid JSON" in err
    alone = CliRunner().invoke(app, ["score", str(tmp_path / "run2")])
    assert alone.exit_code == 2 and "line 3" in alone.output  # named alone, it is an error


def test_exit_codes_tell_the_cases_apart(tmp_path: Path) -> None:
    def summary_of(name: str, poses: list[list[float]], outcome: str = "completed") -> dict:
        write_run(tmp_path / name, config_for("T1"), poses, outcome=outcome)
        return summarize_run(read_run(tmp_path / name), tiny_scenario())

    assert exit_code(summary_of("success", AT_TARGET)) == 0
    assert exit_code(summary_of("far", FAR)) == 1  # COMPLETE 9.74 m from the target is no success
    assert exit_code(summary_of("failed", AT_TARGET[:1], "failed")) == 1
    model = summarize_run(read_run(_aborted(tmp_path / "model", "model")), tiny_scenario())
    outage = summarize_run(read_run(_aborted(tmp_path / "outage", "backend")), tiny_scenario())
    assert exit_code(model) == 3 and exit_code(outage) == 4
