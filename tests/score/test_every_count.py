"""A score column never shows "—" for a value the summaries have: one case per column of every table."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from llmnav.planners.fsm.tables import FSM_TABLE
from llmnav.planners.waypoints.planner.execute import WAYPOINT_TABLE
from llmnav.runs.folders import Run
from llmnav.scoring.score import MISSING, declared_table, episodes_table, path_table
from llmnav.world.tasks import resolve_task

START = resolve_task("factory", None, "T1", 2).start.pose().as_list()  # the oracle's path starts here
FACTORY_T1_POSE2 = {"scenario": "factory", "start_pose": START, "start_pose_index": 2}


def _run(planner: str, summary: dict[str, Any], metrics: dict[str, Any] | None = None) -> Run:
    base = {
        "task_id": "T1",
        "planner": planner,
        "condition": {"planner": planner},
        "scenario": "factory",
        "start_pose_index": 2,
        "success": True,
        "score": 0.9,
        "outcome": "completed",
        "planner_metrics": metrics or {},
    }
    return Run(Path(f"/runs/{planner}"), {**base, **summary}, dict(FACTORY_T1_POSE2))


def _oracle_with_a_veto() -> Run:
    # the case that showed "—": a baseline (no model calls) whose summary counts a safety veto
    return _run(
        "oracle",
        {"llm_calls": 0, "safety_vetoes": 1, "json_errors": 0, "iterations": 9, "latency_s_mean": 0.01,
         "new_prompt_tokens_median": 0, "path_length_m": 11.8},
    )  # fmt: skip


def _cells(table: Any) -> dict[str, str]:
    assert table is not None and len(table.rows) >= 1
    row = table.rows[0]
    return {f"{i}:{name}": cell for i, (name, cell) in enumerate(zip(table.columns, row, strict=True))}


STEPWISE_COLUMNS = ["N", "Iterations", "Latency (s)", "#JSON", "#Safety", "Success", "Score", "New tok"]


@pytest.mark.parametrize("column", STEPWISE_COLUMNS)
def test_episodes_table_shows_every_count_of_a_baseline(column: str) -> None:
    table = episodes_table([_oracle_with_a_veto()], ["planner"])
    cells = {k.split(":", 1)[1]: v for k, v in _cells(table).items()}
    assert cells[column] != MISSING, cells
    if column == "#Safety":
        assert cells[column] == "1.0"
    if column == "#JSON":
        assert cells[column] == "0.0"


def test_episodes_table_still_marks_a_value_no_summary_has() -> None:
    run = _run("oracle", {"llm_calls": 0, "iterations": 3})  # no counts at all
    cells = {k.split(":", 1)[1]: v for k, v in _cells(episodes_table([run], ["planner"])).items()}
    assert cells["#Safety"] == MISSING and cells["#JSON"] == MISSING and cells["Iterations"] == "3.0"


@pytest.mark.parametrize("column", ["N ok", "Path (m)", "Oracle (m)", "Ratio", "Frontier (m)", "Ratio "])
def test_path_table_shows_every_length(column: str) -> None:
    stepwise = _run("stepwise", {"path_length_m": 12.0, "llm_calls": 5})
    frontier = _run("frontier", {"path_length_m": 15.0})
    table = path_table([stepwise, frontier], ["planner"])
    assert table is not None
    row = next(r for r in table.rows if r[1] == "planner=stepwise")
    index = [i for i, c in enumerate(table.columns) if c == column.strip()][1 if column.endswith(" ") else 0]
    assert row[index] != MISSING, dict(zip(table.columns, row, strict=True))


WAYPOINT_METRICS = {
    "planning_time_s": 1.5, "execution_time_s": 20.0, "wgsr": 80.0, "collision_events": 1, "replans": 1,
    "replanning_rate": 0.05,
}  # fmt: skip


@pytest.mark.parametrize("column", ["N", "Planning (s)", "Execution (s)", "Path (m)", "WGSR (%)",
                                    "Collision events", "Replans", "Success"])  # fmt: skip
def test_waypoint_table_shows_every_metric(column: str) -> None:
    run = _run("waypoints", {"path_length_m": 10.0}, WAYPOINT_METRICS)
    cells = {k.split(":", 1)[1]: v for k, v in _cells(declared_table(WAYPOINT_TABLE, [run], ["planner"])).items()}
    assert cells[column] != MISSING, cells


FSM_METRICS = {
    "e_pos_m": 0.2, "eta": 0.9, "tick_latency_ms": {"mean": 1.2}, "model_latency_ms": {"mean": 300.0},
    "r_acc": 0.5, "r_use": 0.4, "suggestions": 10, "accepted": 5,
    "rejected": {"stale": 2, "bounds": 2, "parse": 1},
}  # fmt: skip


@pytest.mark.parametrize("column", ["N", "e_pos (m)", "η", "Loop (ms)", "Model (ms)", "r_acc", "r_use",
                                    "Accepted", "Stale", "Bounds", "Parse", "New tok"])  # fmt: skip
def test_fsm_table_shows_every_metric(column: str) -> None:
    run = _run("fsm", {"new_prompt_tokens_median": 20}, FSM_METRICS)
    cells = {k.split(":", 1)[1]: v for k, v in _cells(declared_table(FSM_TABLE, [run], ["planner"])).items()}
    assert cells[column] != MISSING, cells
