"""`llmnav score` on run folders written with the real RunLog: complete, cut short, several conditions."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

sys.path.insert(0, str(Path(__file__).parent))
from score_fakes import config_for, write_run, write_scenario_file  # noqa: E402

from llmnav.cli import app  # noqa: E402
from llmnav.runs.folders import find_run_dirs, load_runs  # noqa: E402
from llmnav.scoring.score import compare_groups, varying_keys
from llmnav.scoring.tables import build_tables  # noqa: E402


def _make_runs(root: Path) -> None:
    """T1 under sectors 3 and 8 (two start poses each), a T7 run, a cut-short run without summary."""
    finals = {3: [[4.5, 0, 0], [0.5, 0, 0]], 8: [[3.0, 0, 0], [4.0, 0, 0]]}  # d = 0.5/4.5 (3), 2.0/1.0 (8)
    for sectors, ends in finals.items():
        for pose_index, end in enumerate(ends, start=1):
            cfg = config_for("T1", options={"lidar_sectors": sectors}, start_pose_index=pose_index)
            write_run(
                root / f"T1-s{sectors}-p{pose_index}",
                cfg,
                [[0, 0, 0], end],
                summary=True,
                latencies=(1.0, 3.0) if sectors == 3 else (2.0,),
                guards=("parse",) if sectors == 3 else (),
            )
    write_run(root / "T7-s8", config_for("T7", options={"lidar_sectors": 8}), [[0, 0, 0]], summary=True)
    root.mkdir(parents=True, exist_ok=True)
    sc_file = write_scenario_file(root / "tiny.yaml")  # a cut-short run is scored against its scenario file
    cut = write_run(
        root / "deep" / "T1-cut",
        config_for("T1", options={"lidar_sectors": 8}, scenario_file=sc_file),
        [[0, 0, 0], [2.0, 0, 0]],
        outcome=None,
    )
    with open(cut / "run.jsonl", "a") as f:
        f.write('{"type": "pose", "po')


def test_load_group_and_tables(tmp_path: Path) -> None:
    _make_runs(tmp_path)
    assert len(find_run_dirs([tmp_path])) == 6
    runs = load_runs([tmp_path])
    cut = [r for r in runs if r.summary["cut_short"]]
    assert len(cut) == 1 and cut[0].summary["outcome"] == "aborted"
    assert varying_keys(runs) == ["lidar_sectors"]
    tables = build_tables(runs)
    titles = [t.title for t in tables]
    assert any("Table 1" in t for t in titles) and any("Table 2" in t for t in titles)
    assert not any("Waypoint" in t or "FSM" in t for t in titles)  # no data: not shown
    episodes = tables[0]
    rows = {(r[0], r[1]): r for r in episodes.rows}
    s3 = rows[("T1", "lidar_sectors=3")]
    s8 = rows[("T1", "lidar_sectors=8")]
    assert s3[2] == "2" and s3[7] == "1/2"
    assert s8[2] == "3" and s8[7] == "2/3"  # the cut-short run counts as a failure
    assert rows[("T7", "lidar_sectors=8")][8] == "N.A."
    # sectors 3 scores: 1.0 (d=0.5) and 1.5**-2 * 1 (d=4.5) -> mean 0.7222, SD 0.3928
    rec3 = next(r for r in episodes.records if r["task"] == "T1" and r["condition"] == "lidar_sectors=3")
    assert rec3["score"]["mean"] == pytest.approx((1 + 1 / 2.25) / 2, abs=1e-4)
    assert rec3["score"]["sd"] == pytest.approx(math.sqrt(2) * (1 - 1 / 2.25) / 2, abs=1e-4)
    assert rec3["latency_s"]["mean"] == pytest.approx(2.0) and rec3["json_errors"]["mean"] == 1.0
    assert s3[4] == "2.00 ± 0.00"
    path = tables[1]
    prow = {(r[0], r[1]): r for r in path.rows}
    assert prow[("T1", "lidar_sectors=8")][2] == "2"  # successful runs only
    assert prow[("T1", "lidar_sectors=8")][3] == "3.50 ± 0.71"


def test_compare_groups(tmp_path: Path) -> None:
    _make_runs(tmp_path)
    table, results = compare_groups(load_runs([tmp_path]), "lidar_sectors=3", "lidar_sectors=8")
    by_metric = {r.metric: r.result for r in results}
    assert {"score", "success", "path_length_m"} <= set(by_metric)
    assert by_metric["score"].a.n == 2 and by_metric["score"].b.n == 3
    # By hand: sectors 3 scores [1, 1.5**-2] (mean 0.7222, var 0.15432); sectors 8 [1, 1, 1.5**-0.5] (the
    # cut-short run ends 3 m away; mean 0.93883, var 0.011225). Pooled SD sqrt((0.15432 + 2 * 0.011225) / 3)
    # = 0.24274; d = -0.21661 / 0.24274 = -0.89236; J = 1 - 3 / (4 * 5 - 9) = 8/11; g = -0.64898.
    assert by_metric["score"].hedges_g == pytest.approx(-0.64898, abs=1e-4)
    assert by_metric["score"].a.mean == pytest.approx(0.72222, abs=1e-4)
    assert table.rows[0][0] == "score"


def test_waypoint_and_fsm_tables(tmp_path: Path) -> None:
    wp = {
        "planning_time_s": 9.0,
        "execution_time_s": 50.0,
        "generations": 2,
        "valid_generations": 2,
        "wgsr": 100.0,
        "collision_events": 1,
        "replans": 0,
        "replanning_rate": 0.0,
    }
    for i, planning in enumerate((9.0, 11.0)):
        write_run(
            tmp_path / f"wp{i}",
            config_for("T1", planner="waypoints"),
            [[0, 0, 0], [4.0, 0, 0]],
            metrics=wp | {"planning_time_s": planning},
            summary=True,
        )
    for assist, e in (("none", 0.25), ("none", 0.23), ("llm", 0.15), ("llm", 0.17)):
        fsm = {
            "e_pos_m": e,
            "eta": 0.8,
            "tick_latency_ms": {"mean": 3.4, "p50": 3.3, "p99": 5.0, "max": 6.0},
            "model_latency_ms": 186.0,
            "suggestions": 10,
            "accepted": 8,
            "rejected": {"stale": 1, "bounds": 1, "parse": 0},
            "r_acc": 0.8,
            "r_use": 0.5,
        }
        write_run(
            tmp_path / f"fsm-{assist}-{e}",
            config_for("T1", planner="fsm", options={"assist": assist}),
            [[0, 0, 0], [4.0, 0, 0]],
            metrics=fsm,
            summary=True,
        )
    runs = load_runs([tmp_path])
    titles = {t.title.split(" (")[0]: t for t in build_tables(runs)}
    waypoint = titles["Waypoint planner"]
    assert [r[0] for r in waypoint.rows] == ["Go to the pile of pellets", "Average"]
    assert waypoint.rows[0][3] == "10.00 ± 1.41"
    fsm_rows = {r[1]: r for r in titles["FSM with LLM assist"].rows}
    assert fsm_rows["planner=fsm, assist=llm"][3] == "0.160 ± 0.014"
    assert fsm_rows["planner=fsm, assist=none"][5] == "3.40 ± 0.00"
    assert fsm_rows["planner=fsm, assist=llm"][9:13] == ["80%", "10%", "10%", "0%"]  # of 20 suggestions
    _, results = compare_groups(runs, "assist=none", "assist=llm")
    assert any(r.metric == "e_pos_m" and r.result.welch.t > 0 for r in results)


def test_cli_formats_plot_and_errors(tmp_path: Path) -> None:
    runs_dir = tmp_path / "runs"
    _make_runs(runs_dir)
    cli = CliRunner()
    result = cli.invoke(app, ["score", str(runs_dir)])
    assert result.exit_code == 0, result.output
    assert "Success" in result.output and "1/2" in result.output
    out = tmp_path / "t.json"
    result = cli.invoke(
        app,
        [
            "score",
            str(runs_dir),
            "--format",
            "json",
            "--out",
            str(out),
            "--compare",
            "lidar_sectors=3",
            "--compare",
            "lidar_sectors=8",
            "--plot",
            str(tmp_path / "plots"),
        ],
    )
    assert result.exit_code == 0, result.output
    data = json.loads(out.read_text())
    assert data[0]["records"][0]["task"] == "T1" and data[-1]["title"].startswith("Comparison")
    assert result.stdout == ""  # written to --out; the status line went to stderr
    assert "tables written to" in result.stderr
    assert sorted(p.name for p in (tmp_path / "plots").iterdir()) == ["T1.png", "T7.png"]
    assert (tmp_path / "plots" / "T1.png").read_bytes()[:4] == b"\x89PNG"
    md = cli.invoke(app, ["score", str(runs_dir), "--format", "md"]).output
    assert "| Task | Condition |" in md and "| T1 | lidar_sectors=3 |" in md
    csv_text = cli.invoke(app, ["score", str(runs_dir), "--format", "csv"]).stdout
    assert csv_text.splitlines()[0].startswith("task,condition,lidar_sectors,n,successes,success_rate,")
    bad = cli.invoke(app, ["score", str(tmp_path / "nope")])
    assert bad.exit_code == 2 and "no such file" in bad.output and len(bad.output.strip().splitlines()) == 1
    empty = tmp_path / "empty"
    empty.mkdir()
    assert cli.invoke(app, ["score", str(empty)]).exit_code == 2
    assert (
        cli.invoke(app, ["score", str(runs_dir), "--compare", "bogus=1", "--compare", "prompt=x"]).exit_code
        == 2
    )
