"""The generator: its files load, pass `scenarios check`, repeat byte for byte, and keep their promises."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

from llmnav.buildings.check import check_file
from llmnav.buildings.generate import Request, generate
from llmnav.core.robot_specs import ROBOT_SPECS
from llmnav.world.scenario import LabelledObject, Scenario, load_scenario

SEEDS = range(20)


def _written(tmp_path: Path, kind: str, seed: int, **options: object) -> Path:
    path = tmp_path / f"{kind}-{seed}.yaml"
    path.write_text(generate(Request(kind, seed, **options)).text, encoding="utf-8")  # type: ignore[arg-type]
    return path


def _room_of(scenario: Scenario, x: float, y: float) -> str | None:
    """The room floor (room-N) a point stands on, read from the file alone."""
    for obj in scenario.objects:
        if obj.id.startswith("room-") and obj.contains(x, y):
            return obj.id
    return None


@pytest.mark.parametrize("seed", SEEDS)
def test_a_generated_flat_loads_and_passes_check(tmp_path: Path, seed: int) -> None:
    path = _written(tmp_path, "flat", seed)
    scenario = load_scenario(path)
    assert check_file(path) == []
    kinds = {task.kind for task in scenario.tasks}
    assert kinds == {"target", "rotate", "explore"}, kinds
    # Up to 3 start poses each; a target task with targets in most rooms may find fewer places to start.
    assert all(1 <= len(task.start_poses) <= 3 for task in scenario.tasks)
    assert all(len(task.start_poses) == 3 for task in scenario.tasks if task.kind != "target")


@pytest.mark.parametrize(("kind", "seed"), [(k, s) for k in ("office", "warehouse") for s in range(4)])
def test_generated_offices_and_warehouses_pass_check(tmp_path: Path, kind: str, seed: int) -> None:
    path = _written(tmp_path, kind, seed)
    assert check_file(path) == []
    assert load_scenario(path).name == f"{kind}-{seed}"


def test_the_same_seed_gives_the_same_bytes_in_another_process(tmp_path: Path) -> None:
    first = generate(Request("office", 7)).text
    assert generate(Request("office", 7)).text == first
    # A fresh interpreter with other hash seeds: set and dict order must not leak into the file.
    code = "import sys; from llmnav.buildings.generate import Request, generate; "
    code += "sys.stdout.write(generate(Request('office', 7)).text)"
    for hash_seed in ("1", "12345"):
        env = {**os.environ, "PYTHONHASHSEED": hash_seed}
        out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
        assert out.stdout == first


def test_different_seeds_and_kinds_give_different_buildings() -> None:
    texts = {generate(Request("flat", seed)).text for seed in range(5)}
    assert len(texts) == 5
    assert generate(Request("flat", 1)).text != generate(Request("office", 1)).text


def test_start_poses_lie_outside_every_target_room(tmp_path: Path) -> None:
    checked = 0
    for seed in range(6):
        scenario = load_scenario(_written(tmp_path, "flat", seed))
        for task in scenario.tasks:
            target_rooms = set()
            for target in task.targets:
                obj = scenario.object(str(target.object))
                target_rooms.add(obj.id if obj.id.startswith("room-") else _room_of(scenario, *obj.center))
            for start in task.start_poses:
                room = _room_of(scenario, start.x, start.y)
                assert room is not None, (seed, task.id, start)
                assert room not in target_rooms, (seed, task.id, start, room)
                checked += 1
    assert checked > 100


def test_doorways_let_the_robot_through_and_low_furniture_is_there(tmp_path: Path) -> None:
    robot = ROBOT_SPECS["pr2"]
    low: list[LabelledObject] = []
    for seed in range(10):
        scenario = load_scenario(_written(tmp_path, "flat", seed))
        lintels = [w for w in scenario.walls if (w.id or "").startswith("lintel-")]
        assert lintels
        for lintel in lintels:
            assert lintel.size is not None
            assert max(lintel.size) >= robot.width_m + 0.3  # the doorway below it
        low += [o for o in scenario.objects if o.solid and o.height <= 0.45]
    assert {o.label for o in low} & {"coffee table", "footstool"}


def test_warehouses_hold_pallets_lower_than_the_lidar(tmp_path: Path) -> None:
    lidar_m = ROBOT_SPECS["pr2"].lidar_height_m
    pallets = [
        o for s in range(6) for o in load_scenario(_written(tmp_path, "warehouse", s)).objects if o.label == "pallet"
    ]
    assert pallets and all(o.solid and o.height < lidar_m for o in pallets)


def test_aliases_never_hold_a_task_wording(tmp_path: Path) -> None:
    for kind in ("flat", "office", "warehouse"):
        for seed in range(4):
            scenario = load_scenario(_written(tmp_path, kind, seed))
            wordings = {" ".join(w.lower().split()) for t in scenario.tasks for w in (t.text, *t.paraphrases)}
            for obj in scenario.objects:
                for alias in obj.aliases:
                    assert len(alias.split()) <= 3, alias  # a name, not a sentence
                    assert alias.lower() not in wordings


def test_options_change_the_building(tmp_path: Path) -> None:
    scenario = load_scenario(_written(tmp_path, "flat", 3, rooms=3, size_m=(9.0, 7.0), starts=2, robot="burger"))
    assert scenario.robot == "burger"
    assert math.isclose(scenario.bounds.x[1], 9.0) and math.isclose(scenario.bounds.y[1], 7.0)
    assert sum(1 for o in scenario.objects if o.id.startswith("room-")) == 3
    assert all(1 <= len(t.start_poses) <= 2 for t in scenario.tasks)
    assert check_file(tmp_path / "flat-3.yaml") == []


def test_catalogue_names_and_use_wordings_copy_no_bundled_task() -> None:
    from llmnav.buildings.catalogue import ITEMS, USES
    from llmnav.buildings.kinds import ROOM_TYPES
    from llmnav.world.scenario import list_scenarios

    def norm(text: str) -> str:
        return " ".join(text.lower().strip(" ?!.").split())

    tasks = [t for name in list_scenarios() for t in load_scenario(name).tasks]
    bundled = {norm(w) for t in tasks for w in (t.text, *t.paraphrases)}
    names = {norm(n) for item in ITEMS for n in (item.label, *item.aliases)}
    names |= {norm(n) for room in ROOM_TYPES.values() for n in (room.label, *room.aliases)}
    wordings = {norm(w) for texts in USES.values() for w in texts}
    assert not names & bundled
    assert not wordings & bundled


def test_no_two_tasks_of_a_building_ask_for_the_same_targets() -> None:
    for kind in ("flat", "office", "warehouse"):
        for seed in range(5):
            tasks = generate(Request(kind, seed)).scenario.tasks
            sets = [tuple(sorted(str(t.object) for t in task.targets)) for task in tasks if task.targets]
            assert len(sets) == len(set(sets)), (kind, seed, sets)
