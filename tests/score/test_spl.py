"""SPL, Soft-SPL and oracle success on hand-computed episodes, and `score --success-radius` from the log.

The world: a 10 m x 6 m room split by a 0.1 m thick divider (x 3.95-4.05, y 0-3); a crate at G = (7, 1.5);
the PR2 base (radius r = 0.36 m) starts at S = (1, 1.5). The straight line S-G crosses the divider, so the
shortest collision-free path goes over the divider's top, around its two inflated corners: circles of
radius r about C1 = (3.95, 3) and C2 = (4.05, 3).

Shortest path l to within R = 2.5 m of G, by hand:
- tangent from S to the circle about C1: |S C1| = sqrt(2.95^2 + 1.5^2) = 3.30946, t = sqrt(3.30946^2 - r^2)
  = 3.28982;
- the tangent leaves the circle at an angle asin(r / |S C1|) = 6.245 deg above S->C1 (26.94 deg), so it
  meets the circle 33.18 deg before its top: an arc of r * 0.5791 rad = 0.2085 m;
- along the top from x = 3.95 to 4.05: 0.10 m; the mirror arc at C2: 0.2085 m;
- from C2's circle straight toward G (the same tangent, by symmetry: 3.28982 m) until 2.5 m from G: 0.78982.
l = 3.28982 + 0.2085 + 0.10 + 0.2085 + 0.78982 = 4.5966 m.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from llmnav.cli import app
from llmnav.runs.folders import load_run
from llmnav.runs.runlog import RUN_FILE, SUMMARY_FILE, read_run
from llmnav.scoring.metrics import summarize_run
from llmnav.world.scenario import load_scenario

ROOM = """\
name: divided_room
robot: pr2
bounds: {x: [0.0, 10.0], y: [0.0, 6.0]}
walls:
  - {id: divider, center: [4.0, 1.5], size: [0.1, 3.0]}
objects:
  - {id: CR, label: crate, center: [7.0, 1.5], size: [0.4, 0.4], height: 0.5}
tasks:
  - id: T1
    text: Go to the crate
    targets: [{object: CR}]
    start_poses: [{x: 1.0, y: 1.5, yaw_deg: 0}]
default_start: {x: 1.0, y: 1.5}
"""
G = (7.0, 1.5)
SHORTEST_M = 4.5966  # l, worked out in the module docstring
# The scorer's l follows free cells of a 0.05 m grid (kept clear of the inflation by a quarter cell), so it
# may run long by up to ~0.08 m here (about two cells over the divider's top), never short: a grid path
# is a collision-free path, and no collision-free path beats the taut one.
GRID_SLACK_M = 0.08

OVER_THE_TOP = [(1.0, 1.5), (3.5, 3.6), (4.5, 3.6)]  # S, then over the divider (y 3.6 > 3.36)
FINISH = (5.0, 2.0)  # |FINISH G| = sqrt(2^2 + 0.5^2) = 2.0616 m: within 2.5 m


def _write_run(folder: Path, scenario: Path, poses: list[tuple[float, float]], outcome: str, reason: str) -> Path:
    """A run log as the runner writes it: the configuration, pose samples, the end."""
    folder.mkdir(parents=True)
    config = {
        "type": "config",
        "scenario": "divided_room",
        "scenario_file": str(scenario),
        "task": {"id": "T1", "text": "Go to the crate", "kind": "target", "targets": [{"object": "CR"}]},
        "start_pose_index": 1,
        "start_pose": [1.0, 1.5, 0.0],
        "planner": "stepwise",
        "backend": "policy:first",
        "options": {"planner": "stepwise"},
        "seed": 0,
    }
    lines = [config]
    for i, (x, y) in enumerate(poses):
        lines.append({"type": "pose", "t_wall": float(i), "pose": [x, y, 0.0]})
    lines.append({"type": "end", "t_wall": float(len(poses)), "outcome": outcome, "reason": reason, "iterations": 3})
    (folder / RUN_FILE).write_text("".join(json.dumps(line) + "\n" for line in lines))
    return folder


@pytest.fixture
def room(tmp_path: Path) -> Path:
    path = tmp_path / "divided_room.yaml"
    path.write_text(ROOM)
    return path


def _summary(run_dir: Path, scenario: Path, **kwargs: Any) -> dict[str, Any]:
    return summarize_run(read_run(run_dir), load_scenario(str(scenario)), **kwargs)


def test_spl_and_soft_spl_of_a_run_that_succeeds(tmp_path: Path, room: Path) -> None:
    run = _write_run(tmp_path / "ok", room, [*OVER_THE_TOP, FINISH], "completed", "the model reported COMPLETE")
    summary = _summary(run, room)
    # p = |S (3.5, 3.6)| + 1.0 + |(4.5, 3.6) FINISH| = sqrt(6.25 + 4.41) + 1.0 + sqrt(0.25 + 2.56)
    travelled = 3.26497 + 1.0 + 1.67631
    assert summary["path_length_m"] == pytest.approx(travelled, abs=1e-4)
    assert SHORTEST_M <= summary["shortest_path_m"] <= SHORTEST_M + GRID_SLACK_M
    assert summary["success"] is True and summary["oracle_success"] is True
    assert summary["goal_distance_m"] == 0.0  # ended inside the radius: full progress
    # SPL = 1 * l / max(p, l) = 4.5966 / 5.94128 = 0.7737 (the grid's l: up to 0.08 / 5.94 more)
    assert SHORTEST_M / travelled <= summary["spl"] <= (SHORTEST_M + GRID_SLACK_M) / travelled + 1e-4
    assert summary["soft_spl"] == pytest.approx(summary["spl"])
    assert summary["failure_cause"] is None


def test_soft_spl_credits_progress_where_spl_gives_nothing(tmp_path: Path, room: Path) -> None:
    run = _write_run(tmp_path / "short", room, OVER_THE_TOP, "failed", "max iterations (3) reached without COMPLETE")
    summary = _summary(run, room)
    # Stopped at (4.5, 3.6): |(4.5, 3.6) G| = sqrt(2.5^2 + 2.1^2) = 3.26497 and the line to G is clear (past the
    # divider), so d_T = 3.26497 - 2.5 = 0.76497; p = 3.26497 + 1.0 = 4.26497 < l, so max(p, l) = l and
    # Soft-SPL = (1 - d_T / l) * l / l = 1 - 0.76497 / 4.5966 = 0.8336.
    assert summary["goal_distance_m"] == pytest.approx(0.76497, abs=0.03)
    l_m = summary["shortest_path_m"]
    assert SHORTEST_M <= l_m <= SHORTEST_M + GRID_SLACK_M
    assert summary["soft_spl"] == pytest.approx(1 - 0.76497 / l_m, abs=0.01)
    assert 1 - 0.76497 / SHORTEST_M - 0.01 <= summary["soft_spl"] <= 1 - 0.76497 / (SHORTEST_M + GRID_SLACK_M) + 0.01
    assert summary["spl"] == 0.0 and summary["success"] is False
    # closest sample to G: (4.5, 3.6) at 3.265 m, never within 2.5 m
    assert summary["oracle_success"] is False and summary["closest_approach_m"] == pytest.approx(3.26497, abs=1e-4)
    assert summary["failure_cause"] == "cap"


def test_oracle_success_counts_a_pass_within_the_radius(tmp_path: Path, room: Path) -> None:
    # passes FINISH (2.06 m from G), then drives back over the divider and stops there
    run = _write_run(tmp_path / "back", room, [*OVER_THE_TOP, FINISH, (4.5, 3.6)], "completed", "done")
    summary = _summary(run, room)
    assert summary["success"] is False and summary["oracle_success"] is True
    assert summary["closest_approach_m"] == pytest.approx(math.hypot(2.0, 0.5), abs=1e-4)
    assert summary["failure_cause"] == "wrong_place"


def test_success_radius_recomputes_success_from_the_log(tmp_path: Path, room: Path) -> None:
    near = _write_run(tmp_path / "runs" / "near", room, [*OVER_THE_TOP, FINISH], "completed", "done")
    far = _write_run(tmp_path / "runs" / "far", room, OVER_THE_TOP, "completed", "done")
    for run in (near, far):  # summaries as the runner writes them, at the default 2.5 m
        (run / SUMMARY_FILE).write_text(json.dumps(_summary(run, room)))
    assert (load_run(near).summary["success"], load_run(far).summary["success"]) == (True, False)
    # FINISH is 2.06 m from G and (4.5, 3.6) is 3.26 m: at 1.0 m neither succeeds, at 3.5 m both do
    tight = load_run(near, success_radius_m=1.0).summary
    assert tight["success"] is False and tight["spl"] == 0.0 and tight["failure_cause"] == "wrong_place"
    assert tight["success_radius_m"] == 1.0
    wide = load_run(far, success_radius_m=3.5).summary
    assert wide["success"] is True and wide["oracle_success"] is True and wide["failure_cause"] is None

    def successes(*args: str) -> list[int]:
        result = CliRunner().invoke(app, ["score", str(tmp_path / "runs"), "--format", "json", *args])
        assert result.exit_code == 0, result.output
        (episodes,) = [t for t in json.loads(result.stdout) if t["name"] == "episodes"]
        return [r["successes"] for r in episodes["records"]]

    assert successes() == [1]
    assert successes("--success-radius", "1.0") == [0]
    assert successes("--success-radius", "3.5") == [2]


@pytest.mark.parametrize("radius", ["0", "-1", "nan", "inf"])
def test_a_success_radius_that_is_no_distance_is_refused(tmp_path: Path, room: Path, radius: str) -> None:
    _write_run(tmp_path / "runs" / "near", room, [*OVER_THE_TOP, FINISH], "completed", "done")
    result = CliRunner().invoke(app, ["score", str(tmp_path / "runs"), "--success-radius", radius])
    assert result.exit_code == 2
    assert "--success-radius" in result.output and "Traceback" not in result.output
