"""Waypoint validation (source B rules): every rejected point is named with its rule."""

from __future__ import annotations

import math

import pytest

from llmnav.core.geometry import Pose2D
from llmnav.guard.parse import parse_answer
from llmnav.mapping.grid import build_grid
from llmnav.planners.waypoints.planner import PlanRules, map_to_odom, validate_waypoints
from llmnav.planners.waypoints.planner.answers import WaypointList
from llmnav.world.scenario import parse_scenario

# An L-shaped pair of corridors: main along x (y in [-2, 2]), side along y (x in [8, 12]).
L_WORLD = {
    "name": "l_test",
    "robot": "burger",
    "bounds": {"x": [-1, 12], "y": [-2, 12]},
    "walls": [
        {"center": [3.5, 7.0], "size": [9.0, 10.0]},  # the solid block inside the L
    ],
    "corridors": [{"id": "main", "x": [-1, 12], "y": [-2, 2]}, {"id": "side", "x": [8, 12], "y": [-2, 12]}],
    "objects": [{"id": "door", "label": "door", "center": [10, 11], "size": [0.5, 0.1], "solid": False}],
    "waypoint_rules": {"max_waypoints": 4},
}


@pytest.fixture(scope="module")
def world():
    scenario = parse_scenario(L_WORLD, "l_test")
    return scenario, build_grid(scenario)


def check(world, points, target=(10.0, 10.0)):
    scenario, grid = world
    return validate_waypoints(points, (0.0, 0.0), target, scenario, grid, scenario.waypoint_rules)


def test_valid_plan_through_the_junction(world):
    assert check(world, [(5.0, 0.0), (10.0, 0.0), (10.0, 5.0), (10.0, 10.0)]) == []


def test_point_outside_corridor_margin_is_named(world):
    problems = check(world, [(5.0, 1.8), (10.0, 0.0), (10.0, 10.0)])
    assert any("waypoint 1 (5.00, 1.80)" in p and "outside every corridor" in p for p in problems)


def test_too_close_points(world):
    problems = check(world, [(5.0, 0.0), (5.3, 0.0), (10.0, 0.0), (10.0, 10.0)])
    assert any("waypoint 2" in p and "from the previous point" in p for p in problems)


def test_final_point_must_be_on_target(world):
    problems = check(world, [(5.0, 0.0), (10.0, 0.0), (10.0, 9.9)])
    assert any("final waypoint is 0.10 m from the target" in p for p in problems)


def test_corner_cutting_segment_crosses_the_block(world):
    # (0,0) -> (10,10) diagonally cuts through the solid block.
    problems = check(world, [(10.0, 10.0)])
    assert any("segment to waypoint 1" in p and "crosses an obstacle" in p for p in problems)


def test_too_many_waypoints(world):
    problems = check(world, [(2.0, 0.0), (4.0, 0.0), (6.0, 0.0), (10.0, 0.0), (10.0, 10.0)])
    assert any("5 waypoints; at most 4" in p for p in problems)


def test_obstacle_seen_by_lidar_blocks_segment(world):
    scenario, grid = world
    problems = validate_waypoints(
        [(10.0, 0.0), (10.0, 10.0)], (0.0, 0.0), (10.0, 10.0), scenario, grid, scenario.waypoint_rules,
        extra_obstacles=[(5.0, 0.0)],
    )
    assert any("crosses an obstacle near" in p for p in problems)


@pytest.mark.timeout(20)  # 1e300 made the segment sampling run for hours
@pytest.mark.parametrize("x", [1e308, -1e308, 1e300])
def test_a_finite_but_absurd_point_is_a_bounds_error_not_a_parse_error(world, x):
    # The segment to it used to overflow the sample count, and the guard read that as unreadable JSON.
    scenario, grid = world
    rules = PlanRules(scenario, (0.0, 0.0), (10.0, 10.0), grid, [], 0.35)
    result = parse_answer(f'[{{"x": {x!r}, "y": 0}}, {{"x": 10, "y": 10}}]', WaypointList, bounds=rules)
    assert result.outcome == "bounds", result.error
    assert result.error is not None and "outside every corridor" in result.error
    assert len(result.error) < 500  # the coordinate is written short, not as 309 digits


def test_a_far_point_is_checked_quickly_without_a_grid(world):
    scenario, _ = world
    problems = validate_waypoints(
        [(1e308, 1e308), (-1e308, 0.0)], (0.0, 0.0), (10.0, 10.0), scenario, None, scenario.waypoint_rules,
        extra_obstacles=[(5.0, 5.0)],
    )  # fmt: skip
    assert sum("outside every corridor" in p for p in problems) == 2
    assert any("segment to waypoint 1" in p and "near (5.00, 5.00)" in p for p in problems)


def test_map_to_odom_rotation_and_translation():
    start_map = Pose2D(2.0, 1.0, 0.0)
    start_odom = Pose2D(0.0, 0.0, math.pi / 2)
    x, y = map_to_odom((3.0, 1.0), start_map, start_odom)  # 1 m ahead in the map -> 1 m along +y in odom
    assert (round(x, 9), round(y, 9)) == (0.0, 1.0)
