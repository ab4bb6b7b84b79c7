"""The traffic-sign maze: obeying the signs leads to the stop sign, and the camera sees each sign ahead."""

from __future__ import annotations

import math
from collections.abc import Iterator

import pytest

from llmnav.core.geometry import Pose2D
from llmnav.core.robot_specs import ROBOT_SPECS
from llmnav.sim.world import World
from llmnav.world.scenario import LabelledObject, Scenario, load_scenario

ACT_DISTANCE = 0.5  # [m] where the idealised follower stops in front of a wall and obeys its sign


@pytest.fixture(scope="module")
def maze() -> Scenario:
    return load_scenario("maze_arena")


def ray_to_solid(scenario: Scenario, x: float, y: float, yaw: float) -> float:
    """Distance [m] from (x, y) along yaw to the first solid shape (marched in 1 cm steps)."""
    d = 0.0
    while not any(s.contains(x + d * math.cos(yaw), y + d * math.sin(yaw)) for s in scenario.solid_shapes()):
        d += 0.01
        assert d < 10.0, "no wall ahead"
    return d


def sign_ahead(scenario: Scenario, x: float, y: float, yaw: float) -> LabelledObject:
    """The one sign on the wall the robot faces, about ACT_DISTANCE ahead within +-45 deg."""
    found = []
    for sign in (o for o in scenario.objects if o.sign is not None):
        dx, dy = sign.center[0] - x, sign.center[1] - y
        bearing = math.degrees(math.atan2(dy, dx) - yaw + math.pi) % 360 - 180
        if abs(math.hypot(dx, dy) - ACT_DISTANCE) < 0.1 and abs(bearing) < 45:
            found.append(sign)
    assert len(found) == 1, f"at ({x:.2f}, {y:.2f}) facing {math.degrees(yaw):.0f} deg: {found}"
    return found[0]


def follow_signs(scenario: Scenario, start: Pose2D) -> list[tuple[Pose2D, LabelledObject]]:
    """Legs of an ideal follower: (pose at the start of the leg, sign obeyed at its end)."""
    x, y = start.x, start.y
    yaw = round(start.yaw / (math.pi / 2)) * (math.pi / 2)  # the lanes run along the axes
    legs = []
    for _ in range(10):
        leg_start = Pose2D(x, y, yaw)
        ahead = ray_to_solid(scenario, x, y, yaw)
        x, y = x + (ahead - ACT_DISTANCE) * math.cos(yaw), y + (ahead - ACT_DISTANCE) * math.sin(yaw)
        sign = sign_ahead(scenario, x, y, yaw)
        legs.append((leg_start, sign))
        if sign.sign == "stop":
            break
        yaw += math.pi / 2 if sign.sign == "left" else -math.pi / 2
    return legs


def test_following_the_signs_reaches_the_stop_sign(maze: Scenario) -> None:
    task = maze.task("M1")
    (target,) = task.targets
    for start in task.start_poses:
        legs = follow_signs(maze, start.pose())
        classes = [sign.sign for _, sign in legs]
        assert classes[-1] == "stop" and legs[-1][1].id == target.object
        assert "left" in classes and "right" in classes
        assert len(legs) == 5


def test_signs_sit_at_the_burger_camera_height_with_one_colour_per_class(maze: Scenario) -> None:
    camera_z = ROBOT_SPECS["burger"].camera_height_m
    assert maze.robot == "burger"
    colours: dict[str, set[tuple[float, ...]]] = {}
    for sign in (o for o in maze.objects if o.sign is not None):
        assert sign.z <= camera_z <= sign.z + sign.height
        assert sign.size is not None and max(sign.size) == pytest.approx(0.2)
        colours.setdefault(sign.sign or "", set()).add(sign.color)
    assert set(colours) == {"left", "right", "stop"}
    assert all(len(c) == 1 for c in colours.values())  # one colour per class ...
    assert len({next(iter(c)) for c in colours.values()}) == 3  # ... and distinct between classes


@pytest.fixture(scope="module")
def world(maze: Scenario) -> Iterator[World]:
    # The scenario's detector (its range and occlusion rule) without dropout: this checks what is in view.
    with World(maze, detector=maze.sensors.detector.model_copy(update={"dropout": 0.0})) as w:
        yield w


def test_camera_sees_the_next_sign_and_only_it_along_each_leg(world: World, maze: Scenario) -> None:
    """With the default detector, from 2.3 m out the sign to obey is the only sign seen, with its class."""
    for leg_start, sign in follow_signs(maze, maze.task("M1").start_poses[0].pose()):
        length = ray_to_solid(maze, leg_start.x, leg_start.y, leg_start.yaw) - ACT_DISTANCE
        travelled = max(0.0, length + ACT_DISTANCE - 2.3)  # [m] along the leg
        while travelled < length - 0.2:
            pose = Pose2D(
                leg_start.x + travelled * math.cos(leg_start.yaw),
                leg_start.y + travelled * math.sin(leg_start.yaw),
                leg_start.yaw,
            )
            world.reset(pose)
            detections = [d for d in world.detector.detect() if d.sign is not None]
            assert [(d.object_id, d.sign) for d in detections] == [(sign.id, sign.sign)], (pose, detections)
            travelled += 0.5
