"""The guarded motion layer on the real simulator: straight moves and go_to legs are vetoed before the robot
moves, velocity commands are boxed and stopped short of obstacles, and every refusal is logged."""

from __future__ import annotations

import math
from typing import Any

import pytest

from llmnav.core.geometry import Pose2D
from llmnav.guard.view import PlannerWorld
from llmnav.sim.world import World
from llmnav.world.scenario import parse_scenario

WALL_FACE = 2.9  # [m] x of the east wall's west face


class Log:
    """Collects events as the run log would."""

    def __init__(self) -> None:
        self.sim_time = 0.0
        self.events: list[tuple[str, dict[str, Any]]] = []

    def event(self, kind: str, **fields: Any) -> None:
        self.events.append((kind, fields))

    def of(self, kind: str) -> list[dict[str, Any]]:
        return [f for k, f in self.events if k == kind]


@pytest.fixture
def setup():  # noqa: ANN201
    scenario = parse_scenario(
        {
            "name": "box",
            "robot": "burger",
            "bounds": {"x": [-4, 4], "y": [-4, 4]},
            "walls": [
                {"id": "east", "center": [3.0, 0.0], "size": [0.2, 8.0]},
                {"id": "west", "center": [-3.0, 0.0], "size": [0.2, 8.0]},
                {"id": "north", "center": [0.0, 3.0], "size": [8.0, 0.2]},
                {"id": "south", "center": [0.0, -3.0], "size": [8.0, 0.2]},
            ],
            "default_start": {"x": 0.0, "y": 0.0},
        },
        "test",
    )
    with World(scenario) as world:
        log = Log()
        yield world, PlannerWorld(world, log), log


def test_a_drive_into_a_wall_is_refused_without_moving(setup) -> None:
    world, view, log = setup
    world.reset(Pose2D(2.0, 0.0, 0.0))
    result = view.motion.drive(1.0)
    assert (result.stopped_reason, result.distance_m, result.collided) == ("vetoed", 0.0, False)
    assert world.robot.pose().distance_to(2.0, 0.0) < 1e-6 and world.sim_time == 0.0
    (veto,) = log.of("guard")
    assert veto["outcome"] == "veto" and veto["motion"] == "FRONT" and "would collide" in veto["error"]
    assert result.veto == veto["error"]
    # A move that fits goes ahead, and is not logged as a veto.
    assert view.motion.drive(0.3).ok and len(log.of("guard")) == 1


def test_a_go_to_leg_through_an_obstacle_is_vetoed_and_one_beside_it_is_not(setup) -> None:
    world, view, log = setup
    world.add_obstacle(1.0, 0.0, size=0.3)
    world.reset(Pose2D(0.0, 0.0, math.pi / 2))  # facing away: the leg is checked in its own direction
    refused = view.motion.go_to(2.0, 0.0)
    assert refused.stopped_reason == "vetoed" and refused.veto_hit is not None
    hit_x = refused.veto_hit[0] * math.cos(math.pi / 2) - refused.veto_hit[1] * math.sin(math.pi / 2)
    assert hit_x == pytest.approx(0.85, abs=0.03)  # the obstacle's near face, in the world frame
    assert log.of("guard")[0]["parameters"] == [2.0, 0.0]
    passed = view.motion.go_to(0.0, 1.5)
    assert passed.ok and not passed.collided and len(log.of("guard")) == 1


def test_velocity_commands_stop_short_of_a_wall_and_the_override_is_logged(setup) -> None:
    world, view, log = setup
    world.reset(Pose2D(2.0, 0.0, 0.0))
    radius = world.robot.spec.radius_m
    for _ in range(400):  # 8 s at full speed toward a wall 0.9 m ahead
        result = view.motion.velocity_tick(0.4, 0.0, 0.02)
        assert not result.collided
    gap = WALL_FACE - world.robot.pose().x - radius  # [m] between the body and the wall
    assert 0.0 < gap < 0.06
    overrides = log.of("override")
    assert overrides and overrides[-1]["commanded"] == [0.4, 0.0] and overrides[-1]["applied"] == [0.0, 0.0]
    assert len(log.of("guard")) == 1  # one veto for the whole run of overridden ticks
    assert world.motion.collisions == 0
    # turning in place next to the wall stays allowed, and is not an override
    before = len(overrides)
    view.motion.velocity_tick(0.0, 1.0, 0.02)
    assert len(log.of("override")) == before


def test_the_kinematic_box_clips_and_a_non_number_stops(setup) -> None:
    world, view, log = setup
    spec = world.robot.spec
    view.motion.velocity_tick(1e9, -1e9, 0.02)
    assert log.of("override")[-1]["applied"] == [spec.max_linear, -spec.max_angular]
    view.motion.velocity_tick(float("nan"), 0.5, 0.02)
    assert log.of("override")[-1]["applied"] == [0.0, 0.0]
    commanded = len(log.of("override"))
    view.motion.velocity_tick(0.1, 0.2, 0.02)  # inside the box, nothing near: applied as commanded
    assert len(log.of("override")) == commanded
