"""Every start pose connects to every target through free space wide enough for the robot.

An occupancy grid (5 cm cells) marks where the robot's centre may be: at least its radius away from everything
solid. Connected components of that free space then tell whether a start pose can reach a target.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from llmnav.core.robot_specs import ROBOT_SPECS
from llmnav.world.scenario import Scenario, load_scenario

CELL = 0.05  # [m]
REACH = {"factory": 2.5, "corridor_a": 0.05, "corridor_b": 0.05, "corridor_c": 0.05, "maze_arena": 0.6}
# [m] how close the robot centre must get to a target's goal point: source A scores full marks within 2.5 m,
# source B's last waypoint lies within 0.05 m of it, and the maze's follower stops ~0.5 m before the sign.


def free_space(scenario: Scenario) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(labels of connected free components, x of columns, y of rows)."""
    radius = ROBOT_SPECS[scenario.robot].radius_m
    xs = np.arange(scenario.bounds.x[0], scenario.bounds.x[1], CELL) + CELL / 2
    ys = np.arange(scenario.bounds.y[0], scenario.bounds.y[1], CELL) + CELL / 2
    gx, gy = np.meshgrid(xs, ys)
    free = np.ones(gx.shape, dtype=bool)
    for shape in scenario.solid_shapes():
        hx, hy = shape.half_extents()
        near = (np.abs(gx - shape.center[0]) <= hx + radius + CELL) & (
            np.abs(gy - shape.center[1]) <= hy + radius + CELL
        )
        for i, j in zip(*np.nonzero(near), strict=True):
            if shape.distance_to(gx[i, j], gy[i, j]) < radius:
                free[i, j] = False
    labels, _ = ndimage.label(free)
    return labels, xs, ys


@pytest.mark.parametrize("name", ["factory", "corridor_a", "corridor_b", "corridor_c", "maze_arena"])
def test_every_target_is_reachable_from_every_start(name: str) -> None:
    scenario = load_scenario(name)
    labels, xs, ys = free_space(scenario)
    gx, gy = np.meshgrid(xs, ys)
    for task in scenario.tasks:
        if not task.targets:
            continue
        for start in task.start_poses:
            component = labels[np.abs(ys - start.y).argmin(), np.abs(xs - start.x).argmin()]
            assert component > 0, f"{task.id}: start ({start.x}, {start.y}) is not in free space"
            reachable = labels == component
            for point in scenario.target_points(task):
                dist = np.hypot(gx - point[0], gy - point[1])
                closest = float(dist[reachable].min())
                assert closest <= REACH[name] + CELL, (
                    f"{task.id}: {point} only {closest:.2f} m from ({start.x}, {start.y})"
                )


def test_blocked_target_is_detected() -> None:
    """The check can fail: wall off the maze's last lane and the stop sign is out of reach."""
    scenario = load_scenario("maze_arena")
    data = scenario.model_dump()
    data["walls"].append({"id": "plug", "center": [4.45, 4.0], "size": [1.1, 0.1], "height": 0.5})
    blocked = Scenario.model_validate(data)
    labels, xs, ys = free_space(blocked)
    start = blocked.task("M1").start_poses[0]
    component = labels[np.abs(ys - start.y).argmin(), np.abs(xs - start.x).argmin()]
    (goal,) = blocked.target_points(blocked.task("M1"))
    gx, gy = np.meshgrid(xs, ys)
    assert float(np.hypot(gx - goal[0], gy - goal[1])[labels == component].min()) > 1.0
