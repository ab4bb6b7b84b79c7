"""Routes (`routes:` in a scenario): ordered legs with their own targets, run as one task; bad routes are
one-line scenario errors."""

from __future__ import annotations

import copy
from typing import Any

import pytest

from llmnav.errors import ScenarioError
from llmnav.world.scenario import SEQUENCE_JOIN, load_scenario, parse_scenario
from llmnav.world.tasks import resolve_task, sequence_legs

# The bundled routes: (scenario, route id) -> each leg's target object, in order.
ROUTES = {
    ("corridor_a", "RA"): ["WIN", "R105", "R110", "R102", "R107"],
    ("corridor_b", "RB"): ["WIN1", "R105", "R110", "R102", "R107"],
    ("corridor_c", "RC"): ["R107", "ST1", "R201", "R218", "ENT"],
}


@pytest.mark.parametrize(("name", "route_id"), sorted(ROUTES))
def test_a_bundled_route_runs_as_a_task_leg_by_leg(name: str, route_id: str) -> None:
    resolved = resolve_task(name, None, route_id)
    task = resolved.task
    legs = sequence_legs(resolved.scenario, task)
    assert [leg.targets[0].object for leg in legs] == ROUTES[(name, route_id)]
    assert task.text == SEQUENCE_JOIN.join(leg.text for leg in legs)
    assert task.targets == legs[-1].targets  # the episode succeeds at the last leg's target
    start = load_scenario(name).default_start
    assert (resolved.start.x, resolved.start.y) == (start.x, start.y)  # SP: the environment's start point
    assert [leg.id for leg in legs] == [f"{route_id}.{k}" for k in range(1, 6)]


def test_corridor_c_has_the_sources_sp_to_room_107() -> None:
    task = load_scenario("corridor_c").task("C7")
    assert task.targets[0].object == "R107" and (task.start_poses[0].x, task.start_poses[0].y) == (0, -3)


def _with_route(route: dict[str, Any]) -> dict[str, Any]:
    import yaml

    from llmnav.world.scenario import resolve_scenario_path

    data = yaml.safe_load(resolve_scenario_path("corridor_a").read_text())
    data = copy.deepcopy(data)
    data["routes"] = [route]
    return data


LEG = {"text": "Go to room 101", "targets": [{"object": "R101"}]}


@pytest.mark.parametrize(
    ("route", "message"),
    [
        ({"id": "R", "start": {"x": 0, "y": 0}, "legs": [{"text": "Go", "targets": [{"object": "NOPE"}]}]},
         "unknown target id 'NOPE'"),
        ({"id": "A1", "start": {"x": 0, "y": 0}, "legs": [LEG]}, "route id 'A1' is also a task id"),
        ({"id": "R", "start": {"x": 0, "y": 0}, "legs": [{"text": f"Go{SEQUENCE_JOIN}on", "targets": LEG["targets"]}]},
         "may not contain"),
        ({"id": "R", "start": {"x": 0, "y": 0}, "legs": []}, "at least 1"),
        ({"id": "R", "start": {"x": 50, "y": 0}, "legs": [LEG]}, "outside bounds"),
        ({"id": "R", "start": {"x": 0, "y": 0}, "legs": [{"text": "Go to room 101"}]}, "targets"),
    ],
)  # fmt: skip
def test_a_bad_route_is_one_line(route: dict[str, Any], message: str) -> None:
    with pytest.raises(ScenarioError) as caught:
        parse_scenario(_with_route(route), "corridor_a.yaml")
    text = str(caught.value)
    assert message in text and "\n" not in text and "routes" in text
