"""The source papers' tables (`llmnav score --table NAME`, `llmnav.scoring.papers`): each in the layout fixed
below, from run folders written with the real RunLog, and the waypoint legs from a route driven in the
simulator with oracle answers."""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from llmnav.cli import app
from llmnav.runs.folders import load_runs
from llmnav.runs.runlog import SUMMARY_FILE, RunLog, read_run, write_json_atomic
from llmnav.scoring.papers import PAPER_TABLES, table_names
from llmnav.scoring.score import varying_keys
from tests.score.score_fakes import config_for, tiny_scenario, write_run

runner = CliRunner()

# The layouts, fixed here: a change to a paper table's columns or rows must change this file too.
STEPWISE_1 = ["Task", "Iterations", "Latency (s)", "#JSON", "#Safety", "Success", "Score"]
STEPWISE_POSITION = ["Condition", "Position", "Iterations", "Latency (s)", "#JSON", "#Safety", "Success", "Score"]
LEGS = ["Leg", "Planning time (s)", "WGSR (%)", "Replanning", "Execution time (s)", "Path length (m)", "Collision"]
FSM_COMPARE = ["Metric", "FSM-only", "FSM + LLM", "t", "p", "g"]
FSM_COMPARE_ROWS = ["N", "e_pos (m)", "η = L_opt / L_real", "Control-loop latency (ms)", "Model latency (ms)",
                    "Acceptance r_acc", "Utilisation r_use"]  # fmt: skip
FSM_VELOCITY = ["Condition", "Signal", "Samples", "Mean (m/s)", "SD (m/s)", "Min (m/s)", "Max (m/s)"]


def score(*args: str) -> Any:
    return runner.invoke(app, ["score", *args])


def table(root: Path, name: str, by: str | None = None) -> dict[str, Any]:
    """The table as `--format json` gives it, with its display rows from the library."""
    runs = load_runs([root])
    keys = varying_keys(runs) if by is None else [by]
    built = PAPER_TABLES[name](runs, keys)
    assert built is not None
    return {"title": built.title, "columns": built.columns, "rows": built.rows, "records": built.records}


# --- stepwise source --------------------------------------------------------------------------------


def stepwise_runs(root: Path, *, two_conditions: bool = False) -> None:
    """T1 from positions 1 and 2 (two trials at 1), T7 once; #JSON 2 + 1, #Safety 1, in known runs."""
    plan = [
        ("T1", 1, 0, ("parse", "schema", "ok"), [[0, 0, 0], [4.5, 0, 0]]),  # success, 2 JSON errors
        ("T1", 1, 1, ("veto", "ok"), [[0, 0, 0], [0.5, 0, 0]]),  # fails, 1 veto
        ("T1", 2, 0, ("bounds", "ok"), [[0, 3, 0], [4.5, 0.5, 0]]),  # success, 1 JSON error
        ("T7", 1, 0, (), [[0, 0, 0]]),
    ]
    for task, pose, seed, guards, poses in plan:
        cfg = config_for(task, start_pose_index=pose, seed=seed)
        write_run(root / f"{task}-p{pose}-s{seed}", cfg, poses, summary=True, guards=guards, latencies=(1.0, 3.0))
    if two_conditions:
        cfg = config_for("T1", options={"lidar_sectors": 3})
        write_run(root / "T1-s3", cfg, [[0, 0, 0], [4.5, 0, 0]], summary=True, guards=("parse",))


def test_stepwise_1_has_the_sources_columns_and_totals(tmp_path: Path) -> None:
    stepwise_runs(tmp_path)
    t = table(tmp_path, "stepwise-1")
    assert t["columns"] == STEPWISE_1
    assert "backend=replay:x" in t["title"] or "all" in t["title"]  # the one condition is named in the title
    rows = {r[0]: r for r in t["rows"]}
    assert list(rows) == ["T1", "T7"]
    # totals over T1's three runs, not per-run means: 2 + 1 JSON errors, 1 veto
    assert rows["T1"][1:6] == ["1.0", "2.00", "3", "1", "2/3"]
    runs = [r for r in load_runs([tmp_path]) if r.task == "T1"]
    assert float(rows["T1"][6]) == pytest.approx(sum(r.summary["score"] for r in runs) / 3, abs=0.005)
    assert rows["T7"][6] == "N.A."
    record = next(r for r in t["records"] if r["task"] == "T1")
    assert (record["json_errors_total"], record["safety_vetoes_total"], record["successes"], record["n"]) == (
        3, 1, 2, 3,
    )  # fmt: skip


def test_stepwise_1_gets_a_condition_column_when_conditions_differ(tmp_path: Path) -> None:
    stepwise_runs(tmp_path, two_conditions=True)
    t = table(tmp_path, "stepwise-1")
    assert t["columns"] == ["Condition", *STEPWISE_1]
    assert {(r[0], r[1]) for r in t["rows"]} == {("lidar_sectors=8", "T1"), ("lidar_sectors=8", "T7"),
                                                  ("lidar_sectors=3", "T1")}  # fmt: skip


def test_stepwise_position_has_a_row_per_start_position(tmp_path: Path) -> None:
    stepwise_runs(tmp_path)
    t = table(tmp_path, "stepwise-position")
    assert t["columns"] == STEPWISE_POSITION
    assert [r[1] for r in t["rows"]] == ["Position 1", "Position 2"]
    pos1, pos2 = t["rows"]
    assert (pos1[4], pos1[5], pos1[6]) == ("2", "1", "2/3")  # T1 twice and T7 from position 1
    assert (pos2[4], pos2[5], pos2[6]) == ("1", "0", "1/1")


def test_score_by_start_pose(tmp_path: Path) -> None:
    stepwise_runs(tmp_path)
    res = score(str(tmp_path), "--by", "start_pose", "--table", "episodes", "--format", "json")
    assert res.exit_code == 0, res.output
    records = json.loads(res.stdout)[0]["records"]
    assert {(r["task"], r["start_pose"]) for r in records} == {("T1", 1), ("T1", 2), ("T7", 1)}
    assert next(r for r in records if (r["task"], r["start_pose"]) == ("T1", 1))["n"] == 2


# --- waypoint source ----------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def route_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Route RA of corridor_a (five legs) driven by the waypoint planner with oracle answers."""
    from llmnav.planners.base import drive_options
    from llmnav.runs.runner import EpisodeSpec, run_episode

    root = tmp_path_factory.mktemp("route")
    spec = EpisodeSpec(scenario="corridor_a", task_id="RA", options=drive_options("waypoints"),
                       backend="policy:oracle", out_dir=root / "RA")  # fmt: skip
    summary = run_episode(spec)
    assert summary["outcome"] == "completed", summary["reason"]
    return root


def test_route_legs_are_scored_from_the_logged_route(route_run: Path) -> None:
    t = table(route_run, "waypoints-legs")
    assert t["columns"] == LEGS
    assert "(oracle answers)" in t["title"]
    labels = [r[0] for r in t["rows"]]
    assert labels == ["SP → window", "window → room 105", "room 105 → room 110", "room 110 → room 102",
                      "room 102 → room 107", "Average"]  # fmt: skip
    summary = json.loads((route_run / "RA" / SUMMARY_FILE).read_text())
    legs = summary["planner_metrics"]["legs"]
    for previous, leg in zip(legs, legs[1:], strict=False):
        assert leg["start"] == previous["end"]  # each leg starts where the last one ended
    paths = [float(r[5]) for r in t["rows"][:-1]]
    assert sum(paths) == pytest.approx(summary["path_length_m"], abs=0.05)
    assert float(t["rows"][-1][5]) == pytest.approx(sum(paths) / 5, abs=0.01)
    assert [r[2] for r in t["rows"]] == ["100.0"] * 6 and [r[3] for r in t["rows"][:-1]] == ["0"] * 5
    assert [r[6] for r in t["rows"]] == ["No"] * 5 + ["0/5"]
    # the legs' records agree with the log's end points
    window = read_run(route_run / "RA").config["start_pose"]
    assert legs[0]["start"][:2] == pytest.approx(window[:2], abs=1e-3)


def leg(target: str, *, failed: bool = False, path: float = 5.0, exec_s: float = 12.5) -> dict[str, Any]:
    return {
        "command": f"Go to {target}", "target": target, "reached": not failed, "plan_failed": failed,
        "planning_time_s": 2.0, "generations": 3 if failed else 1, "valid_generations": 0 if failed else 1,
        "replans": 0 if failed else 1, "execution_time_s": 0.0 if failed else exec_s,
        "path_length_m": 0.0 if failed else path, "collision_events": 0, "collided": False,
    }  # fmt: skip


def test_failed_plans_are_marked_and_left_out_of_the_averages(tmp_path: Path) -> None:
    """A failed plan drove nothing: 'failed' in its cells, not 0.00 s and 0.00 m in the Average row."""
    legs = [leg("R101", path=4.0, exec_s=10.0), leg("R106", path=6.0, exec_s=20.0), leg("WIN", failed=True)]
    metrics = {"wgsr": 50.0, "legs": legs, "plan_failed": True, "planning_time_s": 6.0, "execution_time_s": 30.0,
               "collision_events": 0, "replans": 2}  # fmt: skip
    cfg = config_for("T1", planner="waypoints")
    write_run(tmp_path / "route", cfg, [[0, 0, 0], [1, 0, 0]], outcome="failed", metrics=metrics, summary=True)
    t = table(tmp_path, "waypoints-legs")
    rows = {r[0]: r for r in t["rows"]}
    failed = next(r for r in t["rows"] if r[0].endswith("WIN"))
    assert (failed[4], failed[5]) == ("failed", "failed") and failed[2] == "0.0"
    average = rows["Average"]
    assert (average[4], average[5]) == ("15.00", "5.00")  # (10 + 20) / 2 s and (4 + 6) / 2 m: the failure is out
    assert (average[1], average[2]) == ("2.00", "40.0")  # WGSR pooled over the legs: 2 valid of 5 attempts
    assert average[3] == "0.7"  # replans per leg: (1 + 1 + 0) / 3, a count
    assert average[6] == "0/2"  # the driven legs with a collision: the failed plan drove nothing


def test_waypoint_table_leaves_failed_plans_out_of_execution_and_path() -> None:
    """The per-command table (`--table waypoints`): the same rule, and replans as counts."""
    from llmnav.planners.waypoints.planner.execute import WAYPOINT_TABLE
    from llmnav.runs.folders import Run
    from llmnav.scoring.score import declared_table

    def run(failed: bool, execution_s: float, path_m: float) -> Run:
        metrics = {"planning_time_s": 1.0, "execution_time_s": execution_s, "wgsr": 100.0, "collision_events": 0,
                   "replans": 2, "plan_failed": failed}  # fmt: skip
        summary = {"planner": "waypoints", "task_id": "A1", "task_text": "Go to room 101", "success": not failed,
                   "path_length_m": path_m, "planner_metrics": metrics}  # fmt: skip
        return Run(Path("x"), summary, {"options": {"planner": "waypoints"}})

    t = declared_table(WAYPOINT_TABLE, [run(False, 30.0, 12.0), run(True, 0.0, 0.0)], [])
    assert t is not None
    average = dict(zip(t.columns, t.rows[-1], strict=True))
    assert (average["Execution (s)"], average["Path (m)"], average["Replans"]) == ("30.00", "12.00", "2.0 ± 0.0")
    only_failed = declared_table(WAYPOINT_TABLE, [run(True, 0.0, 0.0)], [])
    assert only_failed is not None
    cells = dict(zip(only_failed.columns, only_failed.rows[0], strict=True))
    assert (cells["Execution (s)"], cells["Path (m)"]) == ("failed", "failed")


# --- FSM source ---------------------------------------------------------------------------------------


def fsm_run(root: Path, name: str, assist: str, e_pos: float, eta: float, loop_ms: float,
            cmds: list[tuple[str, float, float | None, float]], backend: str | None = None) -> None:  # fmt: skip
    """An FSM run folder: its end metrics and its sampled `cmd` records (state, base v, raw v, fused v)."""
    cfg = config_for("T1", planner="fsm", options={"assist": assist}, backend=backend)
    run_dir = root / name
    with RunLog(run_dir, cfg) as log:
        log.event("pose", pose=[0.0, 0.0, 0.0])
        for state, base, raw, fused in cmds:
            log.event("planner", kind="cmd", state=state, base=[base, 0.0], raw=None if raw is None else [raw, 0.0],
                      fused=[fused, 0.0])  # fmt: skip
        log.event("pose", pose=[2.0, 0.0, 0.0])
        metrics = {"assist": assist, "e_pos_m": e_pos, "eta": eta, "tick_latency_ms": {"mean": loop_ms},
                   "model_latency_ms": None, "r_acc": None, "r_use": 0.0}  # fmt: skip
        log.event("end", outcome="completed", reason="stopped at the stop sign", metrics=metrics)
    from llmnav.scoring.metrics import summarize_run

    write_json_atomic(run_dir / SUMMARY_FILE, summarize_run(read_run(run_dir), tiny_scenario()))


def fsm_runs(root: Path, llm_backend: str | None = None) -> None:
    approach = [("SEARCH", 0.0, None, 0.0), ("APPROACH", 0.06, None, 0.06), ("APPROACH", 0.03, None, 0.03)]
    for k, (e_pos, eta, loop) in enumerate([(0.25, 0.80, 3.3), (0.20, 0.84, 3.4), (0.30, 0.82, 3.5)]):
        fsm_run(root, f"none-{k}", "none", e_pos, eta, loop, approach)
    assisted = [("APPROACH", 0.06, 0.04, 0.05), ("APPROACH", 0.03, 0.01, 0.02), ("APPROACH", 0.0, None, 0.0)]
    for k, (e_pos, eta, loop) in enumerate([(0.15, 0.90, 3.4), (0.12, 0.92, 3.5), (0.18, 0.89, 3.3)]):
        fsm_run(root, f"llm-{k}", "llm", e_pos, eta, loop, assisted, backend=llm_backend)


def test_fsm_compare_has_a_row_per_metric_and_the_loop_latency(tmp_path: Path) -> None:
    fsm_runs(tmp_path)
    t = table(tmp_path, "fsm-compare")
    assert t["columns"] == FSM_COMPARE
    assert [r[0] for r in t["rows"]] == FSM_COMPARE_ROWS
    rows = {r[0]: r for r in t["rows"]}
    assert rows["N"][1:3] == ["3", "3"]
    assert rows["e_pos (m)"][1:3] == ["0.250 ± 0.050", "0.150 ± 0.030"]
    assert rows["Control-loop latency (ms)"][1:3] == ["3.40 ± 0.10", "3.40 ± 0.10"]
    assert float(rows["e_pos (m)"][3]) < 0 and float(rows["η = L_opt / L_real"][3]) > 0  # FSM + LLM against FSM-only


def test_fsm_conditions_say_who_answered(tmp_path: Path) -> None:
    """Oracle answers are marked in the column's name, a model's backend named: never taken for each other."""
    fsm_runs(tmp_path / "oracle", llm_backend="policy:oracle")
    assert table(tmp_path / "oracle", "fsm-compare")["columns"][2] == "FSM + LLM (oracle answers)"
    fsm_runs(tmp_path / "local", llm_backend="local")
    assert table(tmp_path / "local", "fsm-compare")["columns"][2] == "FSM + LLM (local)"
    both = table(tmp_path, "fsm-compare")  # the model last: t and g compare it with FSM-only
    assert both["columns"] == ["Metric", "FSM-only", "FSM + LLM (oracle answers)", "FSM + LLM (local)", "t", "p", "g"]


def test_fsm_velocity_has_baseline_accepted_and_fused_rows(tmp_path: Path) -> None:
    fsm_runs(tmp_path)
    t = table(tmp_path, "fsm-velocity")
    assert t["columns"] == FSM_VELOCITY
    assert [(r[0], r[1]) for r in t["rows"]] == [(c, s) for c in ("FSM-only", "FSM + LLM")
                                                 for s in ("Baseline", "LLM (accepted)", "Fused")]  # fmt: skip
    rows = {(r[0], r[1]): r[2:] for r in t["rows"]}
    assert rows[("FSM-only", "Baseline")][:2] == ["6", "0.0450"]  # APPROACH only: SEARCH is left out
    assert rows[("FSM-only", "LLM (accepted)")] == ["0", "—", "—", "—", "—"]
    assert rows[("FSM + LLM", "LLM (accepted)")][:2] == ["6", "0.0250"]
    assert rows[("FSM + LLM", "Fused")][0] == "6" and rows[("FSM + LLM", "Fused")][3:] == ["0.0200", "0.0500"]


# --- the command ----------------------------------------------------------------------------------------


def test_an_unknown_table_is_one_line_listing_the_names(tmp_path: Path) -> None:
    stepwise_runs(tmp_path)
    res = score(str(tmp_path), "--table", "stepwise-2")
    assert res.exit_code == 2
    lines = [line for line in res.output.splitlines() if line.strip()]
    assert len(lines) == 1 and "--table stepwise-2: unknown table" in lines[0]
    for name in (*PAPER_TABLES, "episodes", "waypoints", "fsm"):
        assert name in lines[0]
    assert set(PAPER_TABLES) <= set(table_names())


def test_a_paper_table_without_its_data_is_one_line(tmp_path: Path) -> None:
    stepwise_runs(tmp_path)
    res = score(str(tmp_path), "--table", "fsm-velocity")
    assert res.exit_code == 2 and "--table fsm-velocity: no run here has FSM metrics" in res.output


@pytest.mark.parametrize("name", sorted(PAPER_TABLES))
def test_every_paper_table_writes_json_and_csv(tmp_path: Path, name: str) -> None:
    stepwise_runs(tmp_path / "stepwise")
    fsm_runs(tmp_path / "fsm")
    metrics = {"wgsr": 100.0, "legs": [leg("R101"), leg("R106")], "plan_failed": False}
    write_run(tmp_path / "legs" / "r", config_for("T1", planner="waypoints"), [[0, 0, 0], [1, 0, 0]],
              metrics=metrics, summary=True)  # fmt: skip
    res = score(str(tmp_path), "--table", name, "--format", "json")
    assert res.exit_code == 0, res.output
    (only,) = json.loads(res.stdout)
    assert only["name"] == name and only["records"]
    res = score(str(tmp_path), "--table", name, "--format", "csv")
    assert res.exit_code == 0, res.output
    parsed = list(csv.DictReader(io.StringIO(res.stdout)))
    assert len(parsed) == len(only["records"]) and "condition" in parsed[0]
