"""Task resolution: exact texts, ad-hoc targets by name and room number, sequences, start poses."""

from __future__ import annotations

from pathlib import Path

import pytest

from llmnav.errors import BadInputError
from llmnav.world.scenario import load_scenario
from llmnav.world.tasks import (
    SEQUENCE_ID,
    adhoc_task,
    default_scenario,
    named_objects,
    resolve_task,
    sequence_legs,
    task_from_text,
)

SMALL = str(Path(__file__).with_name("small_room.yaml"))


def test_exact_task_text_is_the_scenario_task_ignoring_case_and_full_stop() -> None:
    scenario = load_scenario(SMALL)
    task = task_from_text(scenario, "go to the RED box.")
    assert task.id == "T1"


def test_free_text_targets_the_named_objects_longest_name_wins() -> None:
    factory = load_scenario("factory")
    task = adhoc_task(factory, "please drive to the fire extinguisher now")
    assert task.kind == "target"
    assert [t.object for t in task.targets] == ["FE"]
    # "fire" alone names the fire, not the extinguisher
    assert [t.object for t in adhoc_task(factory, "where is the fire").targets] == ["FIRE"]


def test_plural_and_alias_matching() -> None:
    factory = load_scenario("factory")
    ids = {o.id for o in named_objects(factory, "approach the barrels")}
    assert ids == {"OB1", "OB2", "OB3"}


def test_room_number_matches_plates_by_number() -> None:
    scenario = load_scenario(SMALL)
    assert [o.id for o in named_objects(scenario, "Go to room 101")] == ["P101"]
    assert [o.id for o in named_objects(scenario, "101 please")] == ["P101"]
    assert named_objects(scenario, "Go to room 102") == []


def test_text_naming_nothing_is_exploration() -> None:
    task = adhoc_task(load_scenario(SMALL), "wander about a bit")
    assert task.kind == "explore" and task.targets == []


def test_default_scenario_follows_the_task() -> None:
    assert default_scenario(["Go to the pile of pellets"], None) == "factory"
    assert default_scenario(["sing a song"], None) == "factory"
    assert default_scenario(None, "T3") == "factory"


def test_resolve_task_picks_the_start_pose_and_rejects_bad_input() -> None:
    resolved = resolve_task(SMALL, None, "T1", 2)
    assert (resolved.start.x, resolved.start.y) == (5.5, 3.0)
    assert resolved.start_pose_index == 2
    with pytest.raises(BadInputError, match="start poses 1..2"):
        resolve_task(SMALL, None, "T1", 3)
    with pytest.raises(BadInputError, match="no task 'T9'.*T1, T2"):
        resolve_task(SMALL, None, "T9", 1)
    with pytest.raises(BadInputError, match="exactly one"):
        resolve_task(SMALL, ["Go to the red box"], "T1", 1)
    with pytest.raises(BadInputError, match="exactly one"):
        resolve_task(SMALL, None, None, 1)


def test_sequence_of_tasks_round_trips_through_its_legs() -> None:
    resolved = resolve_task(SMALL, ["Go to room 101", "Go to the red box"], None)
    task = resolved.task
    assert task.id == SEQUENCE_ID
    assert [t.object for t in task.targets] == ["RB"]  # the final leg's targets
    legs = sequence_legs(resolved.scenario, task)
    assert [leg.text for leg in legs] == ["Go to room 101", "Go to the red box"]
    assert [t.object for t in legs[0].targets] == ["P101"]
    assert legs[1].id == "T1"
