"""Small in-code scenarios for the simulation tests (no scenario files needed)."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest

from llmnav.sim.world import World
from llmnav.world.scenario import Scenario, parse_scenario

WALL_X = 3.0  # [m] centre of the east wall
WALL_T = 0.2  # [m] wall thickness


def room(robot: str = "pr2", **extra: Any) -> Scenario:
    """A 10 m x 10 m room; the east wall's face is at x = 2.9, the north wall's face at y = 3.9.

    Without a `sensors` section its detector is ideal and its odometry exact (the class defaults); tests
    that want errors pass their own configs.
    """
    data: dict[str, Any] = {
        "name": "room",
        "robot": robot,
        "bounds": {"x": [-5, 5], "y": [-5, 5]},
        "walls": [
            {"id": "east", "center": [WALL_X, 0.0], "size": [WALL_T, 10.0], "height": 2.0},
            {"id": "north", "center": [0.0, 4.0], "size": [10.0, WALL_T], "height": 2.0},
            {"id": "south", "center": [0.0, -4.0], "size": [10.0, WALL_T], "height": 2.0},
            {"id": "west", "center": [-4.0, 0.0], "size": [WALL_T, 10.0], "height": 2.0},
        ],
        "objects": [
            {
                "id": "ball",
                "label": "red ball",
                "shape": "cylinder",
                "center": [2.0, 0.9],
                "radius": 0.25,
                "height": 1.5,
                "color": [1, 0, 0, 1],
                "sign": "left",
            },
            {
                "id": "ghost",
                "label": "blue ghost",
                "center": [2.5, -1.0],
                "size": [0.4, 0.4],
                "height": 1.5,
                "solid": False,
                "color": [0, 0, 1, 1],
            },
        ],
    }
    data.update(extra)
    return parse_scenario(data, "test-room")


@pytest.fixture
def world() -> Iterator[World]:
    with World(room()) as w:
        yield w


@pytest.fixture
def make_room() -> Any:
    """The `room` factory, for tests that need variants."""
    return room
