"""Collisions and failure causes on real runs: PyBullet episodes that fail in different ways, then `llmnav score`.

The suite (small_room, stepwise with scripted replies through the replay backend, and the oracle planner):
- collide: FRONT 2 m under a shelf board the LiDAR cannot see (0.6-1.0 m high), then COMPLETE;
- veto: FRONT 3 m toward a wall 1.9 m ahead, with no veto allowed;
- cap: one rotation, with one iteration allowed;
- bad_json: an answer that is not JSON, with no correction allowed;
- outage: the recording holds one reply and the run asks for a second (the server has no answer);
- wrong_place: COMPLETE at the start, 5 m from the red box;
- not_found: the oracle asked for a spot inside a closed pen whose walls stand 3 m from it.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
import yaml
from typer.testing import CliRunner

from llmnav.backends.replay import ReplayBackend, write_script
from llmnav.cli import app
from llmnav.core.declarations import Column, ScoreTable
from llmnav.errors import LlmnavError
from llmnav.planners.base import drive_options
from llmnav.planners.stepwise.answers import step_answer
from llmnav.runs.folders import load_runs
from llmnav.runs.runner import EpisodeSpec, run_episode
from llmnav.scoring.failures import FAILURE_CAUSES, failure_cause
from llmnav.scoring.score import declared_table

SMALL = Path(__file__).parents[1] / "runner" / "small_room.yaml"
PEN = """\
name: pen
robot: pr2
bounds: {x: [0.0, 12.0], y: [0.0, 12.0]}
walls:
  - {id: pen-south, center: [6.0, 3.0], size: [6.2, 0.2]}
  - {id: pen-north, center: [6.0, 9.0], size: [6.2, 0.2]}
  - {id: pen-west, center: [3.0, 6.0], size: [0.2, 6.2]}
  - {id: pen-east, center: [9.0, 6.0], size: [0.2, 6.2]}
tasks:
  - id: T1
    text: Go to the middle of the pen
    targets: [{point: [6.0, 6.0]}]
    start_poses: [{x: 1.0, y: 1.0, yaw_deg: 0}]
default_start: {x: 1.0, y: 1.0}
"""
EXPECTED = {
    "collide": "collision",
    "veto": "veto",
    "cap": "cap",
    "bad_json": "model_failure",
    "outage": "outage",
    "wrong_place": "wrong_place",
    "not_found": "not_found",
}


def _answer(command: str, parameters: float) -> str:
    return f"```json\n{json.dumps(step_answer(command, parameters, reasoning='scripted'))}\n```"


def _stepwise(root: Path, name: str, replies: list[str], scenario: Path = SMALL, pose: int = 1, **options: Any) -> None:
    replay = ReplayBackend(write_script(root / f"{name}.script", replies, purpose="action", latency_s=0.1))
    spec = EpisodeSpec(
        scenario=str(scenario),
        task_id="T1",
        start_pose=pose,
        options=drive_options(planner="stepwise", sensing=("lidar",), **options),
        backend=replay.spec,
        out_dir=root / "runs" / name,
        plots=False,
    )
    try:
        run_episode(spec, backend_obj=replay)
    except LlmnavError:  # the outage is re-raised after its summary is written, as `drive` exits on it
        assert name == "outage"


@pytest.fixture(scope="module")
def suite(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("failures")
    overhang = yaml.safe_load(SMALL.read_text())
    overhang["obstacles"] = [{"id": "shelf", "center": [3.0, 3.0], "size": [0.4, 2.0], "z": 0.6, "height": 0.4}]
    (root / "overhang.yaml").write_text(yaml.safe_dump(overhang))
    _stepwise(root, "collide", [_answer("FRONT", 2.0), _answer("COMPLETE", 0)], root / "overhang.yaml")
    _stepwise(root, "veto", [_answer("FRONT", 3.0)], pose=2, max_vetoes=0)
    _stepwise(root, "cap", [_answer("ROTATE_LEFT", 30)], max_iterations=1)
    _stepwise(root, "bad_json", ["I would rather not say."], max_corrections=0)
    _stepwise(root, "outage", [_answer("ROTATE_LEFT", 30)], max_iterations=3)
    _stepwise(root, "wrong_place", [_answer("COMPLETE", 0)])
    (root / "pen.yaml").write_text(PEN)
    spec = EpisodeSpec(
        scenario=str(root / "pen.yaml"),
        task_id="T1",
        options=drive_options(planner="oracle"),
        out_dir=root / "runs" / "not_found",
        plots=False,
    )
    run_episode(spec)
    return root / "runs"


def test_a_failure_cause_is_assigned_to_every_failed_run(suite: Path) -> None:
    runs = {run.run_dir.name: run.summary for run in load_runs([suite])}
    assert set(runs) == set(EXPECTED)
    for name, summary in runs.items():
        assert summary["success"] is False, name
        assert summary["failure_cause"] in FAILURE_CAUSES, name
        assert summary["failure_cause"] == EXPECTED[name], (name, summary["outcome"], summary["reason"])
    # what the runner wrote is what score reads: summary.json, not a recomputation
    written = json.loads((suite / "veto" / "summary.json").read_text())
    assert written["failure_cause"] == "veto"

    args = ["score", str(suite), "--by", "planner", "--table", "failures", "--format", "json"]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    (table,) = json.loads(result.stdout)
    counts = {r["condition"]: r for r in table["records"]}
    stepwise, oracle = counts["planner=stepwise"], counts["planner=oracle"]
    assert (stepwise["n"], stepwise["failed"], oracle["n"], oracle["failed"]) == (6, 6, 1, 1)
    assert {cause: stepwise[cause] for cause in FAILURE_CAUSES} == {
        "collision": 1, "not_found": 0, "wrong_place": 1, "cap": 1, "veto": 1, "model_failure": 1, "outage": 1,
    }  # fmt: skip
    assert oracle["not_found"] == 1 and sum(oracle[cause] for cause in FAILURE_CAUSES) == 1


def test_the_collisions_column_shows_a_run_that_collided(suite: Path) -> None:
    result = CliRunner().invoke(app, ["score", str(suite), "--by", "planner", "--table", "episodes", "--format", "md"])
    assert result.exit_code == 0, result.output
    lines = result.stdout.splitlines()
    header = [cell.strip() for cell in next(line for line in lines if line.startswith("| Task")).split("|")[1:-1]]
    column = header.index("Collisions")
    rows = {
        (cells[0], cells[1]): cells
        for cells in ([c.strip() for c in line.split("|")[1:-1]] for line in lines if line.startswith("| T1"))
    }
    # the stepwise runs (the outage is tabled apart): the shelf run's one contact; the oracle's none
    assert rows[("T1", "planner=stepwise")][column] == "1"
    assert rows[("T1", "planner=oracle")][column] == "0"
    # score names the run on stderr, and only there
    named = [line for line in result.stderr.splitlines() if line.startswith("collided:")]
    assert len(named) == 1 and "collide" in named[0] and "1 collision with shelf" in named[0]
    assert "collided" not in result.stdout
    data = CliRunner().invoke(app, ["score", str(suite), "--format", "json"])
    json.loads(data.stdout)  # nothing but the document on stdout
    assert "collided:" in data.stderr

    # a planner's declared table carries the same column
    runs = load_runs([suite])
    spec = ScoreTable("own", "A planner's own table", (Column("iterations", "Iter", source="summary"),))
    table = declared_table(spec, runs, ["planner"], planners={"stepwise"})
    assert table is not None and table.columns[-3:] == ["Collisions", "SPL", "Soft-SPL"]
    (row,) = table.rows
    assert row[table.columns.index("Collisions")] == "1"
    (record,) = table.records
    assert (record["collisions"], record["runs_collided"]) == (1, 1)


def test_collision_is_counted_from_the_end_reason_when_no_action_records_it() -> None:
    # a velocity controller (the FSM) ends on "collided with X" without an `action` event
    from llmnav.scoring.metrics import count_collisions

    assert count_collisions([], {}, "collided with barrel_2") == (1, ["barrel_2"])
    assert count_collisions([{"collided": True, "collision_with": "wall-east"}], {}, "collided with wall-east") == (
        1,
        ["wall-east"],
    )
    assert count_collisions([], {}, "reached target") == (0, [])
    assert count_collisions([], {}, "no collision-free path to any target") == (0, [])


@pytest.mark.parametrize(
    ("summary", "cause"),
    [
        ({"outcome": "not_found", "reason": "explored 93 % of the reachable floor; no landmark fits"}, "not_found"),
        ({"outcome": "failed", "reason": "no reachable frontier left and no target detected"}, "not_found"),
        ({"outcome": "failed", "reason": "target RB detected but unreachable"}, "not_found"),
        ({"outcome": "failed", "reason": "no sign found while searching"}, "not_found"),
        ({"outcome": "failed", "reason": "no finish within 30 decisions"}, "cap"),
        ({"outcome": "failed", "reason": "exploration budget spent (8 frontiers) without detecting a target"}, "cap"),
        ({"outcome": "failed", "reason": "tick budget exhausted (3000 ticks)"}, "cap"),
        ({"outcome": "failed", "reason": "motion vetoed: leg blocked"}, "veto"),
        ({"outcome": "failed", "reason": "path to room 101 still blocked (vetoed) after 3 replans"}, "veto"),
        ({"outcome": "failed", "reason": "no valid waypoints for room 101 after 3 generations"}, "model_failure"),
        ({"outcome": "aborted", "reason": "crash: ValueError: x", "planner_metrics": {}}, "outage"),
        ({"outcome": "completed", "reason": "the model chose to finish", "collisions": 2}, "collision"),
        ({"outcome": "completed", "reason": "the model chose to finish", "success": True}, None),
    ],
)
def test_every_end_the_planners_write_maps_to_one_cause(summary: dict[str, Any], cause: str | None) -> None:
    assert failure_cause(summary) == cause


def test_a_summary_written_before_these_keys_scores_from_its_log(suite: Path, tmp_path: Path) -> None:
    import shutil

    from llmnav.runs.folders import load_run
    from llmnav.scoring.metrics import RESCORED_KEYS

    new = (*RESCORED_KEYS, "collisions", "collided_with")
    for name in ("collide", "cap"):
        old = tmp_path / name
        shutil.copytree(suite / name, old)
        written = json.loads((old / "summary.json").read_text())
        (old / "summary.json").write_text(json.dumps({k: v for k, v in written.items() if k not in new}))
        recomputed = load_run(old).summary
        assert {k: recomputed[k] for k in new} == {k: written[k] for k in new}, name
    result = CliRunner().invoke(app, ["score", str(tmp_path), "--format", "md"])
    assert result.exit_code == 0, result.output
    assert "collided:" in result.stderr and "Collisions" in result.stdout
