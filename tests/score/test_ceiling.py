"""Floor, model and ceiling: the oracle's answers (`policy:oracle`) are the ceiling, never a null policy.

Runs on the tiny scenario, all ending on the x axis facing +x (T1's target at (5, 0); T2 accepts the same
pellets or the boxes behind the robot, which score 0 from there). Ending at x = 4.5 succeeds with score 1;
ending at x = 0.5 fails 4.5 m away with score 1.5 ** -2 = 4/9. Every expected number below is worked out
by hand from these two cases.

    episode  model      policy:first  policy:keyword  policy:oracle
    T1 p1    ok (1)     4/9           4/9             ok (1)
    T1 p2    4/9        4/9           4/9             ok (1)
    T2 p1    ok (1)     4/9           ok (1)          ok (1)
"""

from __future__ import annotations

import csv
import io
import json
import sys
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

sys.path.insert(0, str(Path(__file__).parent))
from score_fakes import config_for, write_run  # noqa: E402

from llmnav.cli import app  # noqa: E402
from llmnav.scoring.policies import _gap_closed  # noqa: E402

HIT, MISS = 4.5, 0.5  # final x: success with score 1; failure 4.5 m away with score 4/9
ORACLE_T1 = "backend=policy:oracle (oracle answers)"


def _run(root: Path, backend: str, task: str, pose: int, x_end: float) -> None:
    name = f"{backend.replace(':', '_')}-{task}-{pose}"
    cfg = config_for(task, backend=backend, start_pose_index=pose)
    write_run(root / name, cfg, [[0.0, 0.0, 0.0], [x_end, 0.0, 0.0]], summary=True)


@pytest.fixture
def runs(tmp_path: Path) -> Path:
    """The episodes of the module docstring."""
    root = tmp_path / "runs"
    finals = {
        "local": (HIT, MISS, HIT),
        "policy:first": (MISS, MISS, MISS),
        "policy:keyword": (MISS, MISS, HIT),
        "policy:oracle": (HIT, HIT, HIT),
    }
    for backend, (t1p1, t1p2, t2p1) in finals.items():
        _run(root, backend, "T1", 1, t1p1)
        _run(root, backend, "T1", 2, t1p2)
        _run(root, backend, "T2", 1, t2p1)
    return root


def _invoke(*args: str) -> Any:
    result = CliRunner().invoke(app, ["score", *args])
    assert result.exit_code == 0, result.output
    return result


def _table(root: Path, name: str) -> dict[str, dict[str, Any]]:
    (table,) = json.loads(_invoke(str(root), "--format", "json", "--table", name).stdout)
    return {r["task"]: r for r in table["records"]}


def test_floor_model_and_ceiling_on_the_same_episodes(runs: Path) -> None:
    rows = _table(runs, "ceiling")
    assert list(rows) == ["T1", "T2", "All tasks"]
    t1 = rows["T1"]
    # T1: first and keyword tie (0/2, 4/9): the alphabetically first is the floor
    assert (t1["condition"], t1["backend"], t1["floor_policy"]) == ("backend=local", "local", "policy:first")
    assert (t1["floor"]["successes"], t1["floor"]["n"]) == (0, 2)
    assert t1["floor"]["score_mean"] == pytest.approx(0.4444, abs=1e-4)  # 4/9
    assert (t1["model"]["successes"], t1["model"]["n"]) == (1, 2)
    assert t1["model"]["score_mean"] == pytest.approx(0.7222, abs=1e-4)  # (1 + 4/9) / 2 = 13/18
    assert (t1["ceiling"]["successes"], t1["ceiling"]["n"], t1["ceiling"]["score_mean"]) == (2, 2, 1.0)
    # success (0.5 - 0) / (1 - 0); score (13/18 - 8/18) / (18/18 - 8/18)
    assert t1["gap_closed_success"] == pytest.approx(0.5)
    assert t1["gap_closed_score"] == pytest.approx(0.5)
    assert (t1["n"], t1["n_score"]) == (2, 2)

    every = rows["All tasks"]
    # policy:keyword 1/3 beats policy:first 0/3; model 2/3, score (1 + 4/9 + 1) / 3 = 22/27
    assert every["floor_policy"] == "policy:keyword"
    assert (every["floor"]["successes"], every["model"]["successes"], every["ceiling"]["successes"]) == (1, 2, 3)
    assert every["floor"]["score_mean"] == pytest.approx(0.6296, abs=1e-4)  # (4/9 + 4/9 + 1) / 3 = 17/27
    assert every["model"]["score_mean"] == pytest.approx(0.8148, abs=1e-4)  # 22/27
    # success (2/3 - 1/3) / (1 - 1/3); score (22/27 - 17/27) / (27/27 - 17/27)
    assert every["gap_closed_success"] == pytest.approx(0.5)
    assert every["gap_closed_score"] == pytest.approx(0.5)
    assert every["n"] == 3


def test_no_share_when_the_ceiling_is_the_floor(runs: Path) -> None:
    t2 = _table(runs, "ceiling")["T2"]
    # policy:keyword reaches T2 as the oracle answers do: 1/1, score 1 on both sides, no gap to close
    assert t2["floor_policy"] == "policy:keyword"
    assert (t2["floor"]["successes"], t2["ceiling"]["successes"]) == (1, 1)
    assert t2["gap_closed_success"] is None and t2["gap_closed_score"] is None
    line = _md_row(runs, "ceiling", "T2")
    assert line[9:11] == ["—", "—"]


def test_the_gap_share() -> None:
    assert _gap_closed(0.5, 0.0, 1.0) == pytest.approx(0.5)
    assert _gap_closed(1.2, 0.2, 0.7) == pytest.approx(2.0)  # a model above the ceiling closes more than all
    assert _gap_closed(0.1, 0.2, 0.7) == pytest.approx(-0.2)  # below the floor: negative
    assert _gap_closed(0.5, 1.0, 1.0) is None  # ceiling == floor
    assert _gap_closed(0.5, 0.8, 0.6) is None  # ceiling under the floor: no gap either
    assert _gap_closed(None, 0.0, 1.0) is None


def test_the_oracle_is_never_the_floor_nor_a_model(runs: Path) -> None:
    rows = _table(runs, "null_policies")
    assert list(rows) == ["T1", "T2", "All tasks"]  # no row for the oracle as a model condition
    for row in rows.values():
        assert row["condition"] == "backend=local"
        assert row["best_policy"] != "policy:oracle"
        assert set(row["policies"]) == {"policy:first", "policy:keyword"}
    for row in _table(runs, "ceiling").values():
        assert row["floor_policy"] in {"policy:first", "policy:keyword"}


def _md_row(root: Path, table: str, task: str, condition: str = "backend=local") -> list[str]:
    text = _invoke(str(root), "--format", "md", "--table", table).stdout
    line = next(row for row in text.splitlines() if row.startswith(f"| {task} | {condition} |"))
    return [c.strip() for c in line.strip("|").split("|")]


def test_the_human_table_names_the_ceiling_as_oracle_answers(runs: Path) -> None:
    text = _invoke(str(runs), "--format", "md", "--table", "ceiling").stdout
    assert "### Floor, model and ceiling (same episodes)" in text
    assert "Oracle answers success" in text and "no gap to close" in text
    row = _md_row(runs, "ceiling", "T1")
    assert row[2:11] == [
        "policy:first", "0/2", "0.44 (n=2)", "1/2", "0.72 (n=2)", "2/2", "1.00 (n=2)", "50% (n=2)", "50% (n=2)",
    ]  # fmt: skip
    assert row[11] == "0 / 0 / 0"  # collisions of floor / model / ceiling: these runs touched nothing


def test_the_oracle_runs_are_labelled_in_the_episode_table(runs: Path) -> None:
    (table,) = json.loads(_invoke(str(runs), "--format", "json", "--table", "episodes").stdout)
    oracle = [r for r in table["records"] if r["backend"] == "policy:oracle"]
    assert [(r["task"], r["condition"], r["successes"], r["n"]) for r in oracle] == [
        ("T1", ORACLE_T1, 2, 2),
        ("T2", ORACLE_T1, 1, 1),
    ]
    # grouped by another key, the oracle's runs still stand apart from the model's and say what they are
    (table,) = json.loads(_invoke(str(runs), "--format", "json", "--table", "episodes", "--by", "prompt").stdout)
    labels = {r["condition"] for r in table["records"]}
    assert labels == {"prompt=full", "prompt=full (oracle answers)"}


def test_json_and_csv_hold_the_new_fields(runs: Path) -> None:
    data = json.loads(_invoke(str(runs), "--format", "json").stdout)
    assert [t["name"] for t in data] == ["episodes", "path", "null_policies", "ceiling", "failures"]
    rows = list(csv.DictReader(io.StringIO(_invoke(str(runs), "--format", "csv", "--table", "ceiling").stdout)))
    assert [r["task"] for r in rows] == ["T1", "T2", "All tasks"]
    t1, t2, _ = rows
    assert {"floor_policy", "floor_success_rate", "model_score_mean", "ceiling_n", "n", "n_score"} <= set(t1)
    assert (t1["floor_successes"], t1["model_successes"], t1["ceiling_successes"], t1["n"]) == ("0", "1", "2", "2")
    assert float(t1["gap_closed_success"]) == pytest.approx(0.5)
    assert float(t1["gap_closed_score"]) == pytest.approx(0.5)
    assert (t2["gap_closed_success"], t2["gap_closed_score"]) == ("", "")  # undefined: empty, not 0


def test_floor_and_ceiling_without_a_model(tmp_path: Path) -> None:
    root = tmp_path / "runs"
    _run(root, "policy:first", "T1", 1, MISS)
    _run(root, "policy:oracle", "T1", 1, HIT)
    _run(root, "policy:oracle", "T1", 2, HIT)  # no null policy ran pose 2: not in the row
    assert "null_policies" not in {t["name"] for t in json.loads(_invoke(str(root), "--format", "json").stdout)}
    rows = _table(root, "ceiling")
    assert list(rows) == ["T1", "All tasks"]
    t1 = rows["T1"]
    assert (t1["condition"], t1["floor_policy"], t1["n"]) == (ORACLE_T1, "policy:first", 1)
    assert (t1["model"]["n"], t1["floor"]["successes"], t1["ceiling"]["successes"], t1["ceiling"]["n"]) == (0, 0, 1, 1)
    # no gap to close in any row: the fields are left out of the JSON (nothing to show), not null
    assert "gap_closed_success" not in t1 and "gap_closed_score" not in t1
    row = _md_row(root, "ceiling", "T1", ORACLE_T1)
    assert row[2:11] == [
        "policy:first", "0/1", "0.44 (n=1)", "—", "—", "1/1", "1.00 (n=1)", "—", "—",
    ]  # fmt: skip
    assert row[11] == "0 / — / 0"  # no model side
