"""Frontier exploration in the sim: LiDAR map, detection, shortest path to the target (corridor_a, a room)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from llmnav.baselines.frontier import FrontierConfig, FrontierPlanner
from llmnav.core.geometry import Pose2D
from llmnav.guard.view import PlannerWorld
from llmnav.mapping.grid import GridGeometry, LidarMap
from llmnav.planners.base import EpisodeContext, drive_options
from llmnav.runs.runlog import RunLog, read_run
from llmnav.sim.world import World
from llmnav.world.scenario import Scenario, load_scenario, parse_scenario


def run(sc: Scenario, task_id: str, tmp_path: Path, config: FrontierConfig | None = None):  # noqa: ANN201
    task = sc.task(task_id)
    with World(sc) as world:
        world.reset(sc.start_poses(task)[0].pose())
        with RunLog(tmp_path, {"test": True}) as log:
            world.motion.on_pose = lambda pose, t: log.event("pose", pose=pose.as_list())
            ctx = EpisodeContext(sc, task, PlannerWorld(world, log), None, log, drive_options(planner="frontier"))
            outcome = FrontierPlanner(config).run(ctx)
        final = world.robot.pose()
        collisions = world.motion.collisions
    return outcome, final, collisions, read_run(tmp_path)


def test_frontier_reaches_the_window_of_corridor_a(tmp_path: Path) -> None:
    sc = load_scenario("corridor_a")
    task = next(t for t in sc.tasks if any(tg.object == "WIN" for tg in t.targets))
    outcome, final, collisions, record = run(sc, task.id, tmp_path)
    assert outcome.outcome == "completed", outcome.reason
    # The window has a stand point (`goal`): the robot stops on it and faces the window itself.
    window = sc.object("WIN")
    assert final.distance_to(*window.goal_point) <= 0.15
    assert abs(final.bearing_to(*window.center)) < math.radians(5)
    assert collisions == 0
    # The window is 13 m away: beyond the detector's range from the start, so the robot had to explore
    # first, and it only saw the window after driving.
    detections = [e for e in record.of_type("planner") if e.get("kind") == "frontier_detection"]
    assert detections and detections[0]["object"] == "WIN"
    assert detections[0]["pose"][0] > 0.5
    assert any(e.get("kind") == "frontier_goal" for e in record.of_type("planner"))
    # Reported length = the distance driven, which the logged trajectory confirms.
    poses = np.array(record.poses())
    driven = float(np.hypot(*np.diff(poses[:, :2], axis=0).T).sum())
    assert abs(outcome.metrics["frontier_length_m"] - driven) < 0.15
    assert outcome.metrics["frontier_length_m"] >= math.dist((0.0, 0.0), window.goal_point) - 0.15


# A room with an L-shaped wall hiding the target from the start: the LiDAR map must grow around it.
HIDDEN = {
    "name": "hidden-crate",
    "robot": "burger",
    "bounds": {"x": [0.0, 8.0], "y": [0.0, 6.0]},
    "walls": [
        {"center": [4.0, 0.05], "size": [8.0, 0.1]},
        {"center": [4.0, 5.95], "size": [8.0, 0.1]},
        {"center": [0.05, 3.0], "size": [0.1, 6.0]},
        {"center": [7.95, 3.0], "size": [0.1, 6.0]},
        {"center": [4.0, 2.3], "size": [0.2, 4.6]},  # divider, open at the top
    ],
    "objects": [{"id": "crate", "label": "crate", "center": [6.5, 1.0], "size": [0.5, 0.5], "height": 0.5}],
    "tasks": [
        {
            "id": "find",
            "text": "Find the crate",
            "targets": [{"object": "crate"}],
            "start_poses": [{"x": 1.5, "y": 1.0, "yaw_deg": 0}],
        },
        {"id": "look", "text": "Look around", "kind": "explore"},
    ],
    "default_start": {"x": 1.5, "y": 1.0},
}


def test_frontier_explores_round_a_wall(tmp_path: Path) -> None:
    sc = parse_scenario(HIDDEN, "hidden-crate")
    outcome, final, collisions, record = run(sc, "find", tmp_path)
    assert outcome.outcome == "completed", outcome.reason
    assert 1.4 <= final.distance_to(6.5, 1.0) <= 2.5
    assert collisions == 0
    assert outcome.metrics["frontiers_visited"] >= 1
    detection = next(e for e in record.of_type("planner") if e.get("kind") == "frontier_detection")
    assert detection["pose"][1] > 2.0  # seen only after getting round the divider's open end


def test_frontier_maps_a_box_below_the_lidar_with_the_low_scanner_and_never_touches_it(tmp_path: Path) -> None:
    # A 0.1 m high box: below the Burger's LiDAR (0.17 m), in the low scanner's plane (0.06 m).
    data = dict(HIDDEN, obstacles=[{"center": [2.0, 2.0], "size": [0.4, 0.4], "height": 0.1}])
    sc = parse_scenario(data, "hidden-low-box")
    outcome, final, collisions, _record = run(sc, "find", tmp_path)
    assert outcome.outcome == "completed", outcome.reason
    assert 1.4 <= final.distance_to(6.5, 1.0) <= 2.5
    assert collisions == 0
    assert outcome.metrics["bumps"] == 0


def test_frontier_recovers_from_bumping_into_what_no_scanner_can_see(tmp_path: Path) -> None:
    # A shelf from 0.09 to 0.15 m: above the low scanner (0.06 m), below the Burger's LiDAR (0.17 m), within
    # the height of the robot's body, so the robot can touch it.
    shelf = {"center": [2.0, 2.0], "size": [0.4, 0.4], "height": 0.06, "z": 0.09}
    data = dict(HIDDEN, obstacles=[shelf])
    sc = parse_scenario(data, "hidden-low-box")
    outcome, final, collisions, record = run(sc, "find", tmp_path)
    assert outcome.outcome == "completed", outcome.reason
    assert 1.4 <= final.distance_to(6.5, 1.0) <= 2.5
    assert outcome.metrics["bumps"] == collisions >= 1
    actions = record.of_type("action")
    hit = next(i for i, a in enumerate(actions) if a["collided"])
    assert actions[hit]["collision_with"] == "obstacle:0"
    assert actions[hit + 1]["command"] in ("BACK", "FRONT") and not actions[hit + 1]["collided"]
    assert collisions <= 2  # marked in the map after a bump: not hit over and over


def test_frontier_budget_exhausted_fails_with_reason(tmp_path: Path) -> None:
    sc = parse_scenario(HIDDEN, "hidden-crate")
    outcome, _final, _collisions, _record = run(sc, "find", tmp_path, FrontierConfig(max_frontiers=0))
    assert outcome.outcome == "failed" and "budget" in outcome.reason


def test_frontier_explore_task_ends_at_once(tmp_path: Path) -> None:
    sc = parse_scenario(HIDDEN, "hidden-crate")
    outcome, final, _collisions, _record = run(sc, "look", tmp_path)
    assert outcome.outcome == "completed" and outcome.reason == "no target"
    assert final.distance_to(1.5, 1.0) < 0.01


def test_lidar_map_from_the_real_lidar_matches_the_corridor() -> None:
    sc = load_scenario("corridor_a")
    with World(sc) as world:
        world.reset(Pose2D(0.0, 0.0, 0.0))
        lidar_map = LidarMap(GridGeometry.from_bounds(sc.bounds, 0.05))
        lidar_map.integrate(world.robot.pose(), world.lidar.scan())
    g = lidar_map.geometry
    assert lidar_map.free[g.world_to_cell(5.0, 1.5)] and lidar_map.free[g.world_to_cell(8.0, -1.5)]
    assert lidar_map.occupied[g.world_to_cell(3.0, 2.0)] or lidar_map.occupied[g.world_to_cell(3.0, 2.02)]
    assert lidar_map.unknown[g.world_to_cell(13.0, 0.0)]  # beyond the 10 m range
