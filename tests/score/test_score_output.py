"""`llmnav score` output for machines and for honest comparisons.

- `--format json|csv` write only data to stdout (parsed here with json.loads and csv); status goes to stderr.
- CSV is one tidy table; `--table NAME` picks another.
- Whatever cannot be computed (a scenario that does not load, an oracle that raises) is named on stderr
  with its run.
- The null-policy table puts each model condition beside the best null policy on the same episodes, and
  the wording tables give success and score per wording and their spread.

Expected numbers are worked out by hand from the final poses (tiny scenario: T1's target at (5, 0), full
score within 2.5 m; facing +x; beyond 2.5 m the score is 1.5 ** -(d - 2.5)).
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
from score_fakes import config_for, write_run, write_scenario_file  # noqa: E402

from llmnav.cli import app  # noqa: E402

FAR = 1.5**-2  # score of a run ending 4.5 m from the target, facing it


def _run(root: Path, name: str, task: str, backend: str, pose: int, x_end: float, **task_fields: Any) -> None:
    cfg = config_for(task, backend=backend, start_pose_index=pose)
    cfg["task"].update(task_fields)
    write_run(root / name, cfg, [[0.0, 0.0, 0.0], [x_end, 0.0, 0.0]], summary=True)


@pytest.fixture
def policy_runs(tmp_path: Path) -> Path:
    """A model ('local') and two null policies on T1 (poses 1, 2) and T2 (pose 1)."""
    root = tmp_path / "runs"
    _run(root, "m-T1-1", "T1", "local", 1, 4.5)  # success, score 1
    _run(root, "m-T1-2", "T1", "local", 2, 0.5)  # fails 4.5 m away: score 1.5**-2
    _run(root, "m-T2-1", "T2", "local", 1, 4.5)  # success, score 1
    _run(root, "f-T1-1", "T1", "policy:first", 1, 4.0)  # success, 1
    _run(root, "f-T1-2", "T1", "policy:first", 2, 3.0)  # success, 1
    _run(root, "f-T2-1", "T2", "policy:first", 1, -1.0)  # 6 m from pellets: 1.5**-3.5; faces away from boxes
    _run(root, "r-T1-1", "T1", "policy:random:1", 1, 0.5)  # only pose 1 was run with this policy
    return root


def _invoke(*args: str) -> Any:
    return CliRunner().invoke(app, ["score", *args])


def test_json_on_stdout_is_only_json(policy_runs: Path) -> None:
    result = _invoke(str(policy_runs), "--format", "json")
    assert result.exit_code == 0, result.output
    data = json.loads(result.stdout)  # nothing but the document
    assert [t["name"] for t in data] == ["episodes", "path", "null_policies", "failures"]
    assert "7 run(s) read" in result.stderr and "run(s) read" not in result.stdout


def test_csv_is_one_tidy_table_and_table_picks_another(policy_runs: Path) -> None:
    result = _invoke(str(policy_runs), "--format", "csv")
    assert result.exit_code == 0, result.output
    rows = list(csv.DictReader(io.StringIO(result.stdout)))
    # a row per task x condition, metrics as columns, raw numbers
    assert [(r["task"], r["condition"]) for r in rows] == [
        ("T1", "backend=local"),
        ("T1", "backend=policy:first"),
        ("T1", "backend=policy:random:1"),
        ("T2", "backend=local"),
        ("T2", "backend=policy:first"),
    ]
    assert [r["backend"] for r in rows] == ["local", "policy:first", "policy:random:1", "local", "policy:first"]
    local_t1 = rows[0]
    assert (local_t1["n"], local_t1["successes"]) == ("2", "1")
    assert float(local_t1["score_mean"]) == pytest.approx((1 + FAR) / 2, abs=1e-4)
    assert {"score_sd", "score_ci95_low", "score_ci95_high", "latency_s_mean"} <= set(local_t1)
    assert "--table" in result.stderr  # the other tables are named on stderr, not mixed into the data

    result = _invoke(str(policy_runs), "--format", "csv", "--table", "null_policies")
    rows = list(csv.DictReader(io.StringIO(result.stdout)))
    assert rows[0]["task"] == "T1" and rows[0]["best_policy"] == "policy:first"
    assert float(rows[0]["delta_success_rate"]) == pytest.approx(-0.5)


def test_unknown_table_is_one_line_exit_2(policy_runs: Path) -> None:
    result = _invoke(str(policy_runs), "--format", "csv", "--table", "nope")
    assert result.exit_code == 2 and result.stdout == ""
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "--table nope" in lines[0] and "null_policies" in lines[0]


def test_null_policy_beside_each_model_condition(policy_runs: Path) -> None:
    result = _invoke(str(policy_runs), "--format", "json", "--table", "null_policies")
    (table,) = json.loads(result.stdout)
    rows = {r["task"]: r for r in table["records"]}
    t1 = rows["T1"]
    # policy:first on both T1 poses: 2/2, score 1; the model 1/2, mean (1 + 1.5**-2) / 2 = 0.7222
    assert t1["best_policy"] == "policy:first"
    assert (t1["model"]["n"], t1["model"]["successes"], t1["null"]["successes"]) == (2, 1, 2)
    assert t1["delta_success_rate"] == pytest.approx(-0.5)
    assert t1["delta_score"] == pytest.approx((1 + FAR) / 2 - 1, abs=1e-4)
    assert t1["null_matches_model"] is True
    # policy:random:1 ran pose 1 only: compared on that one episode (model 1/1, policy 0/1)
    random_t1 = t1["policies"]["policy:random:1"]
    assert (random_t1["model"]["n"], random_t1["model"]["successes"], random_t1["null"]["successes"]) == (1, 1, 0)
    t2 = rows["T2"]
    assert t2["delta_success_rate"] == pytest.approx(1.0) and t2["null_matches_model"] is False
    assert t2["null"]["score_mean"] == pytest.approx(1.5**-3.5, abs=1e-4)
    every = rows["All tasks"]
    # all three shared episodes: the model 2/3, policy:first 2/3; scores (1 + FAR + 1)/3 vs (1 + 1 + 1.5**-3.5)/3
    assert (every["model"]["successes"], every["null"]["successes"], every["model"]["n"]) == (2, 2, 3)
    assert every["delta_score"] == pytest.approx((2 + FAR) / 3 - (2 + 1.5**-3.5) / 3, abs=1e-4)
    assert every["null_matches_model"] is False  # same success, lower score


def test_the_null_policy_table_shows_n_and_the_match(policy_runs: Path) -> None:
    result = _invoke(str(policy_runs), "--format", "md", "--table", "null_policies")
    line = next(row for row in result.stdout.splitlines() if row.startswith("| T1 |"))
    cells = [c.strip() for c in line.strip("|").split("|")]
    assert cells[2:10] == ["1/2", "0.72 (n=2)", "policy:first", "2/2", "1.00 (n=2)", "-0.50", "-0.28", "YES"]


def test_success_and_score_per_wording_and_spread(tmp_path: Path) -> None:
    root = tmp_path / "runs"
    _run(root, "b1", "T1", "local", 1, 4.5, wording="bundled")  # success, 1
    _run(root, "b2", "T1", "local", 2, 0.5, wording="bundled")  # fail, FAR
    reworded = {"wording": "paraphrase:1", "text": "Head over to the heap of pellets"}
    _run(root, "p1", "T1", "local", 1, 0.5, **reworded)  # fail, FAR
    _run(root, "p2", "T1", "local", 2, 0.5, **reworded)  # fail, FAR
    result = _invoke(str(root), "--format", "json")
    tables = {t["name"]: t["records"] for t in json.loads(result.stdout)}
    per = {(r["task"], r["wording"]): r for r in tables["wording"]}
    assert (per[("T1", "bundled")]["successes"], per[("T1", "bundled")]["n"]) == (1, 2)
    assert per[("T1", "paraphrase:1")]["success_rate"] == 0.0
    assert per[("T1", "paraphrase:1")]["score_mean"] == pytest.approx(FAR, abs=1e-4)
    spread = next(r for r in tables["wording_spread"] if r["task"] == "T1")
    assert spread["wordings"] == 2
    assert spread["success_rate_range"] == pytest.approx(0.5)
    assert spread["success_rate_sd"] == pytest.approx(0.5 / 2**0.5)  # SD of [0.5, 0]
    assert spread["score_range"] == pytest.approx((1 + FAR) / 2 - FAR, abs=1e-4)


def test_what_cannot_be_computed_is_named_with_its_run(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    root = tmp_path / "runs"
    loads = config_for("T1", backend="local", scenario_file=write_scenario_file(tmp_path / "tiny.yaml"))
    write_run(root / "ok", loads, [[0.0, 0.0, 0.0], [4.5, 0.0, 0.0]], summary=True)
    # a run cut short whose scenario file is gone: its summary must be rebuilt without the scenario
    lost = config_for("T1", backend="local", scenario="gone", scenario_file=tmp_path / "gone.yaml")
    write_run(root / "lost", lost, [[0.0, 0.0, 0.0], [4.5, 0.0, 0.0]], outcome=None)

    import llmnav.mapping.targets as oracle

    def broken(*args: Any, **kwargs: Any) -> float:
        raise RuntimeError("grid exploded")

    monkeypatch.setattr(oracle, "oracle_path", broken)
    result = _invoke(str(root), "--format", "json")
    assert result.exit_code == 0, result.output
    json.loads(result.stdout)  # the data still parses
    errors = result.stderr
    assert f"{root / 'lost'}: scenario" in errors and "cannot be loaded" in errors
    assert f"{root / 'ok'}: no oracle path length: RuntimeError: grid exploded" in errors
