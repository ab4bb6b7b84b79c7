"""Metric definitions against hand-computed values, and summarize_run on real run folders."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))
from score_fakes import config_for, tiny_scenario, write_run  # noqa: E402

from llmnav.core.geometry import Pose2D, path_length  # noqa: E402
from llmnav.runs.runlog import read_run  # noqa: E402
from llmnav.scoring.metrics import (  # noqa: E402
    best_target,
    distance_score,
    heading_score,
    score_pose,
    summarize_run,
    total_rotation,
)


def test_distance_score_hand_values() -> None:
    assert distance_score(0.0) == 1.0
    assert distance_score(2.5) == 1.0
    assert distance_score(3.0) == pytest.approx(0.8165, abs=5e-5)  # 1.5 ** -0.5
    assert distance_score(4.5) == pytest.approx(1 / 2.25)
    assert distance_score(10.0) < distance_score(9.0) < 1.0


def test_heading_score_hand_values() -> None:
    assert heading_score(0.0) == 1.0
    assert heading_score(math.pi / 2) == pytest.approx(0.5)
    assert heading_score(-math.pi / 2) == pytest.approx(0.5)
    assert heading_score(math.pi) == pytest.approx(0.0)
    assert heading_score(math.pi / 4) == pytest.approx(0.75)


def test_score_pose_combines_both() -> None:
    # 3 m away, target straight to the left: 0.8165 * 0.5
    s = score_pose(Pose2D(0.0, 0.0, 0.0), (0.0, 3.0))
    assert s.distance_m == pytest.approx(3.0)
    assert s.heading_error_rad == pytest.approx(math.pi / 2)
    assert s.score == pytest.approx(0.8165 * 0.5, abs=1e-4)


def test_best_target_takes_max_score_not_nearest() -> None:
    pose = Pose2D(0.0, 0.0, 0.0)
    # nearer target behind (score 0) vs a farther one straight ahead
    best = best_target(pose, [(-2.0, 0.0), (4.0, 0.0)])
    assert best is not None and best.index == 1
    assert best.score == pytest.approx(1.5**-1.5)
    assert best_target(pose, []) is None


def test_path_length_and_rotation() -> None:
    assert path_length([[0, 0, 0], [3, 4, 0], [3, 4, 1.0], [3, 0, 0]]) == pytest.approx(9.0)
    assert path_length([]) == 0.0
    # a full left turn sampled every 60 degrees (yaw wraps at pi)
    turn = [[0, 0, math.atan2(math.sin(a), math.cos(a))] for a in [math.radians(60 * k) for k in range(7)]]
    assert total_rotation(turn) == pytest.approx(2 * math.pi, abs=1e-9)
    # left 180 and back right 180 is no full turn
    back = [[0, 0, y] for y in (0.0, 1.5, 3.0, 1.5, 0.0)]
    assert total_rotation(back) == pytest.approx(3.0)


def test_summarize_completed_target_run(tmp_path: Path) -> None:
    run = write_run(
        tmp_path / "r",
        config_for("T1"),
        [[0, 0, 0], [1.5, 0, 0], [3.0, 0, 0]],
        latencies=(1.0, 2.0, 4.5),
        guards=("ok", "parse", "schema", "veto", "bounds"),
    )
    s = summarize_run(read_run(run), tiny_scenario())
    assert s["outcome"] == "completed" and not s["cut_short"]
    assert s["task_id"] == "T1" and s["task_kind"] == "target"
    assert s["distance_m"] == pytest.approx(2.0)
    assert s["score"] == pytest.approx(1.0) and s["success"] is True
    assert s["path_length_m"] == pytest.approx(3.0)
    assert s["latency_s_mean"] == pytest.approx(2.5)
    assert s["json_errors"] == 3 and s["safety_vetoes"] == 1
    assert s["iterations"] == 2
    assert s["final_pose"] == [3.0, 0.0, 0.0]
    assert s["condition"]["sensing"] == "lidar+image" and s["condition"]["lidar_sectors"] == 8
    assert s["sim_time_s"] == pytest.approx(2.0)


def test_summarize_far_completed_is_not_success(tmp_path: Path) -> None:
    run = write_run(tmp_path / "r", config_for("T1"), [[0, 0, 0], [0.5, 0, math.pi / 2]])
    s = summarize_run(read_run(run), tiny_scenario())
    assert s["distance_m"] == pytest.approx(4.5)
    assert s["score"] == pytest.approx((1 / 2.25) * 0.5, abs=1e-4)
    assert s["success"] is False


def test_summarize_best_of_two_targets(tmp_path: Path) -> None:
    run = write_run(tmp_path / "r", config_for("T2"), [[0, 0, 0], [-3.5, 0, math.pi]])
    s = summarize_run(read_run(run), tiny_scenario())
    assert s["target_index"] == 1 and s["success"] is True and s["score"] == pytest.approx(1.0)


def test_summarize_cut_short_run(tmp_path: Path) -> None:
    run = write_run(tmp_path / "r", config_for("T1"), [[0, 0, 0], [3.0, 0, 0]], outcome=None)
    with open(run / "run.jsonl", "a") as f:
        f.write('{"type": "pose", "pose": [9, 9')  # torn by a kill
    record = read_run(run)
    assert record.torn_lines == 1
    s = summarize_run(record, tiny_scenario())
    assert s["outcome"] == "aborted" and s["cut_short"] is True and s["success"] is False
    assert s["score"] == pytest.approx(1.0)  # the final pose still scores


def test_summarize_rotate_and_explore(tmp_path: Path) -> None:
    turn = [[0, 0, math.atan2(math.sin(a), math.cos(a))] for a in [math.radians(45 * k) for k in range(9)]]
    s = summarize_run(read_run(write_run(tmp_path / "a", config_for("T6"), turn)), tiny_scenario())
    assert s["score"] == 1.0 and s["success"] is True
    assert s["rotation_total_rad"] == pytest.approx(2 * math.pi, abs=1e-4)
    half = turn[:5]
    s = summarize_run(read_run(write_run(tmp_path / "b", config_for("T6"), half)), tiny_scenario())
    assert s["score"] == 0.0 and s["success"] is False
    s = summarize_run(read_run(write_run(tmp_path / "c", config_for("T7"), [[0, 0, 0]])), tiny_scenario())
    assert s["score"] is None and s["success"] is True
    s = summarize_run(
        read_run(write_run(tmp_path / "d", config_for("T7"), [[0, 0, 0]], outcome="failed")), tiny_scenario()
    )
    assert s["success"] is False


def test_summarize_passes_planner_metrics_and_outcome(tmp_path: Path) -> None:
    from llmnav.planners.base import EpisodeOutcome

    run = write_run(tmp_path / "r", config_for("T1"), [[0, 0, 0]], outcome=None)
    outcome = EpisodeOutcome("failed", "max iterations", iterations=30, metrics={"wgsr": 95.5})
    s = summarize_run(read_run(run), tiny_scenario(), outcome)
    assert s["outcome"] == "failed" and s["iterations"] == 30 and s["planner_metrics"] == {"wgsr": 95.5}
    assert s["cut_short"] is False


def test_summarize_without_scenario_uses_logged_points(tmp_path: Path) -> None:
    config = config_for("T1")
    config["task"]["targets"] = [{"point": [4.0, 0.0]}]
    s = summarize_run(read_run(write_run(tmp_path / "r", config, [[0, 0, 0], [1.0, 0, 0]])), None)
    assert s["distance_m"] == pytest.approx(3.0) and s["score"] == pytest.approx(0.8165, abs=1e-4)
    config["task"]["targets"] = [{"object": "pellets"}]  # an object needs the scenario: nothing to score
    s = summarize_run(read_run(write_run(tmp_path / "q", config, [[0, 0, 0]])), None)
    assert s["score"] is None and s["success"] is False
