"""The five bundled scenario files: they load, their tasks and targets are consistent, the geometry works."""

from __future__ import annotations

import math

import pytest

from llmnav.core.robot_specs import ROBOT_SPECS
from llmnav.world.scenario import Scenario, list_scenarios, load_scenario

BUNDLED = ["corridor_a", "corridor_b", "corridor_c", "factory", "maze_arena"]

# Source A's task list, verbatim (docs/sources.md, A).
FACTORY_TASKS = {
    "T1": ("Go to the pile of pellets", "target", "medium"),
    "T2": ("Find an object I can use to carry some beers", "target", "hard"),
    "T3": ("Look if something is inside the red box", "target", "medium"),
    "T4": ("Go between the stairs and the oil barrels", "target", "hard"),
    "T5": ("Look for some stairs", "target", "medium"),
    "T6": ("Make a 360-degree turn", "rotate", "easy"),
    "T7": ("Look around", "explore", "easy"),
    "T8": ("Go to the pile of dark brown boxes", "target", "medium"),
    "T9": ("Look for a red cylindrical fire extinguisher", "target", "medium"),
    "T10": ("There's a fire!", "target", "hard"),
}
START_CLEARANCE = 0.6  # [m] free space around the robot's footprint at every start pose


def test_all_bundled_scenarios_are_listed_and_load() -> None:
    assert list_scenarios() == BUNDLED
    for name in BUNDLED:
        scenario = load_scenario(name)
        assert scenario.name == name
        assert scenario.tasks, name


@pytest.mark.parametrize("name", BUNDLED)
def test_task_targets_exist_and_every_task_has_a_start(name: str) -> None:
    scenario = load_scenario(name)
    for task in scenario.tasks:
        for target in task.targets:
            if target.object is not None:
                scenario.object(target.object)  # KeyError if missing
            else:
                assert target.point is not None and scenario.bounds.contains(*target.point)
        assert task.start_poses, task.id


@pytest.mark.parametrize("name", BUNDLED)
def test_start_poses_keep_clear_of_everything_solid(name: str) -> None:
    scenario = load_scenario(name)
    radius = ROBOT_SPECS[scenario.robot].radius_m
    # The maze's lanes are 1.6 m wide: there the robot only needs its own footprint plus a little.
    clearance = START_CLEARANCE if name == "factory" else 0.2
    for task in scenario.tasks:
        for start in task.start_poses:
            gap = min(s.distance_to(start.x, start.y) for s in scenario.solid_shapes()) - radius
            assert gap >= clearance, f"{task.id} start ({start.x}, {start.y}) only {gap:.2f} m clear"


def test_factory_tasks_match_the_source() -> None:
    scenario = load_scenario("factory")
    assert scenario.robot == "pr2"
    assert [t.id for t in scenario.tasks] == list(FACTORY_TASKS)
    for task in scenario.tasks:
        text, kind, difficulty = FACTORY_TASKS[task.id]
        assert (task.text, task.kind, task.difficulty) == (text, kind, difficulty)
        assert len(task.start_poses) == 5
        assert len({(s.x, s.y, s.yaw_deg) for s in task.start_poses}) == 5
    # The acceptable targets the brief names.
    labels = {t.id: {scenario.object(x.object).label for x in t.targets if x.object} for t in scenario.tasks}
    assert labels["T2"] == {"plastic crate", "red plastic basket"}
    assert labels["T3"] == {"red plastic basket"}
    assert labels["T10"] == {"fire", "fire extinguisher"}
    assert labels["T5"] == {"stairs"}
    assert labels["T8"] == {"dark brown wooden boxes"}
    assert scenario.object("FE").color[0] > 0.8 and scenario.object("FE").shape == "cylinder"


def test_factory_t4_point_lies_in_the_gap_between_stairs_and_barrels() -> None:
    scenario = load_scenario("factory")
    ((x, y),) = scenario.target_points(scenario.task("T4"))
    stairs = [s for s in scenario.solid_shapes() if (getattr(s, "id", "") or "").startswith("S")]
    barrels = [scenario.object(i) for i in ("OB1", "OB2", "OB3")]
    assert len(stairs) == 10
    # The robot fits there, north of the foot of the stairs and south of the barrels ...
    assert min(s.distance_to(x, y) for s in scenario.solid_shapes()) > ROBOT_SPECS["pr2"].radius_m
    assert (
        max(s.center[1] + s.half_extents()[1] for s in stairs)
        < y
        < min(b.center[1] - b.radius for b in barrels)
    )
    # ... and the two nearest things to it are a step and a barrel.
    near = sorted(scenario.solid_shapes(), key=lambda s: s.distance_to(x, y))[:2]
    assert sorted(getattr(s, "id", "")[:2] for s in near) == ["OB", "S-"]


@pytest.mark.parametrize("name", ["corridor_a", "corridor_b", "corridor_c"])
def test_corridor_goal_points_satisfy_the_waypoint_margin(name: str) -> None:
    scenario = load_scenario(name)
    margin = scenario.waypoint_rules.margin_m
    assert margin == pytest.approx(0.5)
    for obj in scenario.objects:
        assert any(c.contains(*obj.goal_point, margin=margin) for c in scenario.corridors), obj.id
    start = scenario.default_start
    assert any(c.contains(start.x, start.y, margin=margin) for c in scenario.corridors)


def _free(scenario: Scenario, x: float, y: float) -> bool:
    """A point of the floor that no wall covers."""
    return not any(w.contains(x, y) for w in scenario.walls)


@pytest.mark.parametrize("name", ["corridor_a", "corridor_b", "corridor_c"])
def test_corridor_rectangles_cover_exactly_the_walled_free_space(name: str) -> None:
    scenario = load_scenario(name)
    bx, by = scenario.bounds.x, scenario.bounds.y
    step = 0.25  # [m] sampling grid, offset from the wall faces (multiples of 0.05)
    inside, outside = 0, 0
    for i in range(int((bx[1] - bx[0]) / step)):
        for j in range(int((by[1] - by[0]) / step)):
            x, y = bx[0] + (i + 0.43) * step, by[0] + (j + 0.43) * step
            in_corridor = any(c.contains(x, y) for c in scenario.corridors)
            if in_corridor:
                inside += 1
                assert _free(scenario, x, y), f"wall inside a corridor at ({x:.2f}, {y:.2f})"
            else:
                outside += 1
    assert inside > 100
    # Walls enclose the corridors: walking out of a corridor in any direction hits a wall first.
    for corridor in scenario.corridors:
        cx, cy = (corridor.x[0] + corridor.x[1]) / 2, (corridor.y[0] + corridor.y[1]) / 2
        for angle in range(0, 360, 15):
            dx, dy = math.cos(math.radians(angle)), math.sin(math.radians(angle))
            d, hit = 0.0, False
            while d < 60.0 and scenario.bounds.contains(cx + d * dx, cy + d * dy):
                px, py = cx + d * dx, cy + d * dy
                if not _free(scenario, px, py):
                    hit = True
                    break
                assert any(c.contains(px, py) for c in scenario.corridors), (
                    f"free space outside the corridors at ({px:.2f}, {py:.2f})"
                )
                d += 0.02
            assert hit, f"no wall from {corridor.id} towards {angle} deg"


def test_corridor_sizes_match_the_source() -> None:
    def dims(name: str) -> dict[str, tuple[float, float]]:
        return {c.id: (c.x[1] - c.x[0], c.y[1] - c.y[0]) for c in load_scenario(name).corridors}

    assert dims("corridor_a") == {"main": (15.0, 4.0)}
    assert dims("corridor_b") == {"main": (10.0, 4.0), "side": (4.0, 18.0)}
    assert dims("corridor_c") == {"main": (18.0, 5.0), "corridor1": (5.0, 29.5), "corridor2": (5.0, 29.5)}
    assert [
        load_scenario(n).waypoint_rules.max_waypoints for n in ("corridor_a", "corridor_b", "corridor_c")
    ] == [
        3,
        4,
        6,
    ]
    rooms = {
        n: sorted(o.label for o in load_scenario(n).objects if o.label.startswith("room "))
        for n in ("corridor_a", "corridor_b", "corridor_c")
    }
    assert rooms["corridor_a"] == [f"room {n}" for n in range(101, 111)]
    assert rooms["corridor_b"] == [f"room {n}" for n in range(101, 111)]
    assert rooms["corridor_c"] == [f"room {n}" for n in [*range(101, 115), *range(201, 219)]]
    assert (load_scenario("corridor_c").default_start.x, load_scenario("corridor_c").default_start.y) == (
        0.0,
        -3.0,
    )
