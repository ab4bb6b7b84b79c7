"""`scenarios generate`: a procedurally generated building as a scenario file, the same seed giving the same bytes.

The recipe is ProcTHOR's (Deitke et al., "ProcTHOR: Large-Scale Embodied AI Using Procedural Generation",
NeurIPS 2022), reduced to a flat floor: the room types of the kind (`kinds`), a floor plan (`layout`: rooms,
doorways, walls), objects placed by room type (`furnish`), then tasks whose start poses the checker passes
(`tasks`). Every random draw comes from one `random.Random` seeded with the kind and the seed, and every
number is snapped or rounded, so the text depends on nothing else (not the machine, not hash seeds).
"""

from __future__ import annotations

import random
from dataclasses import dataclass, replace
from typing import Any

from llmnav.buildings.emit import to_yaml
from llmnav.buildings.furnish import Placed, furnish
from llmnav.buildings.kinds import KINDS, ROOM_TYPES, room_types_for
from llmnav.buildings.layout import INNER_WALL_M, JAMB_M, FloorPlan, plan_floor, snap
from llmnav.buildings.tasks import Placement, make_tasks
from llmnav.core.robot_specs import ROBOT_SPECS
from llmnav.errors import BadInputError
from llmnav.world.scenario import Scenario, parse_scenario

GENERATOR_VERSION = 1  # bump when the same request would give different bytes
MIN_SIDE_M = 4.0  # [m] smallest building side accepted
MAX_SIDE_M = 80.0  # [m] largest (the checker rasterises at most 10 000 m²)
MAX_STARTS = 10  # start poses per task
MAX_SUITE = 1000  # buildings in one suite
WALL_HEIGHT_M = 2.5  # [m]
DOOR_HEIGHT_M = 2.1  # [m] lintels above the doorways fill the wall up from here
WALL_COLOR = (0.86, 0.85, 0.8, 1.0)
# Sensing of the bundled PR2 hall (factory.yaml, docs/sensing.md): a detector for objects a metre or so across
# whose range is good to ~5 %, and the odometry of a heavy base on a hard floor.
SENSORS: dict[str, Any] = {
    "detector": {
        "max_distance_m": 12.0,
        "occlusion": "mask",
        "distance_noise_std_m": 0.05,
        "distance_noise_per_m": 0.05,
        "distance_bias": 0.0,
        "bearing_noise_std_deg": 1.0,
        "dropout": 0.02,
    },
    "odometry": {"wheel_scale_std": 0.002, "track_scale_std": 0.01, "wheel_noise_m_per_sqrt_m": 0.005},
}


@dataclass(frozen=True)
class Request:
    """What to generate; `None` fields take the kind's defaults."""

    kind: str
    seed: int
    rooms: int | None = None
    size_m: tuple[float, float] | None = None  # [m] outer (x, y)
    starts: int = 3  # start poses per task
    robot: str | None = None


@dataclass(frozen=True)
class Building:
    """A generated building: its scenario and the file text."""

    scenario: Scenario
    text: str


def _num(value: float) -> float:
    """A coordinate as written: rounded to the millimetre (no 0.30000000000000004)."""
    return round(float(value), 3) + 0.0  # + 0.0 turns -0.0 into 0.0


def _validated(request: Request) -> tuple[Any, int, tuple[float, float], str]:
    """The kind, room count, size and robot of a request, or BadInputError naming what is impossible."""
    if request.kind not in KINDS:
        raise BadInputError(f"unknown building kind '{request.kind}' (kinds: {', '.join(KINDS)})")
    kind = KINDS[request.kind]
    rooms = kind.rooms if request.rooms is None else request.rooms
    if rooms < 1:
        raise BadInputError(f"--rooms {rooms}: a building has at least 1 room")
    if rooms > kind.max_rooms:
        raise BadInputError(f"--rooms {rooms}: a generated {kind.name} has at most {kind.max_rooms} rooms")
    size = kind.size_m if request.size_m is None else request.size_m
    if not all(MIN_SIDE_M <= side <= MAX_SIDE_M for side in size):
        raise BadInputError(
            f"--size {size[0]:g}x{size[1]:g}: each side must lie between {MIN_SIDE_M:g} and {MAX_SIDE_M:g} m"
        )
    size = (snap(size[0], 0.1), snap(size[1], 0.1))
    robot = request.robot or kind.robot
    if robot not in ROBOT_SPECS:
        raise BadInputError(f"--robot {robot}: unknown robot (robots: {', '.join(ROBOT_SPECS)})")
    if not 1 <= request.starts <= MAX_STARTS:
        raise BadInputError(f"--starts {request.starts}: between 1 and {MAX_STARTS} start poses per task")
    if request.seed < 0:
        raise BadInputError(f"--seed {request.seed}: seeds are 0 or more")
    return kind, rooms, size, robot


def _walls(plan: FloorPlan) -> list[dict[str, Any]]:
    walls: list[dict[str, Any]] = []
    for k, box in enumerate(plan.walls, start=1):
        walls.append(
            {
                "id": f"wall-{k}",
                "center": [_num(box.center[0]), _num(box.center[1])],
                "size": [_num(box.size[0]), _num(box.size[1])],
                "height": WALL_HEIGHT_M,
                "color": list(WALL_COLOR),
            }
        )
    for k, door in enumerate(plan.doors, start=1):  # lintels: the wall above each doorway
        along = [door.width_m, INNER_WALL_M] if door.axis == "x" else [INNER_WALL_M, door.width_m]
        walls.append(
            {
                "id": f"lintel-{k}",
                "center": [_num(door.center[0]), _num(door.center[1])],
                "size": [_num(along[0]), _num(along[1])],
                "z": DOOR_HEIGHT_M,
                "height": _num(WALL_HEIGHT_M - DOOR_HEIGHT_M),
                "color": list(WALL_COLOR),
            }
        )
    return walls


def _objects(plan: FloorPlan, placed: list[Placed]) -> tuple[list[dict[str, Any]], Placement]:
    objects: list[dict[str, Any]] = []
    room_of: dict[str, int] = {}
    item_of: dict[str, str] = {}
    room_ids: dict[int, str] = {}
    for room in plan.rooms:  # each room's floor: a labelled, walk-over patch that a room task targets
        kind = ROOM_TYPES[room.type_key]
        inside = room.inside
        obj_id = f"room-{room.index + 1}"
        objects.append(
            {
                "id": obj_id,
                "label": kind.label,
                "aliases": list(kind.aliases),
                "center": [_num(inside.centre[0]), _num(inside.centre[1])],
                "size": [_num(inside.width), _num(inside.depth)],
                "height": 0.01,
                "solid": False,
                "color": list(kind.floor),
            }
        )
        room_of[obj_id], room_ids[room.index] = room.index, obj_id
    counts: dict[str, int] = {}
    for piece in placed:
        item = piece.item
        counts[item.key] = counts.get(item.key, 0) + 1
        obj_id = f"{item.key}-{counts[item.key]}"
        obj: dict[str, Any] = {"id": obj_id, "label": item.label, "aliases": list(item.aliases)}
        if item.cylinder:
            obj.update(
                {"shape": "cylinder", "center": [_num(v) for v in piece.center], "radius": _num(item.width_m / 2)}
            )
        else:
            obj.update({"center": [_num(v) for v in piece.center], "size": [_num(v) for v in piece.size]})
        if item.z_m:
            obj["z"] = item.z_m
        obj["height"] = item.height_m
        if not item.solid:
            obj["solid"] = False
        obj["color"] = list(item.color)
        objects.append(obj)
        room_of[obj_id], item_of[obj_id] = piece.room, item.key
    return objects, Placement(room_of, item_of, room_ids)


def generate(request: Request) -> Building:
    """The building a request describes (BadInputError when it is impossible)."""
    kind, rooms, size, robot = _validated(request)
    rng = random.Random(f"llmnav-building:{kind.name}:{request.seed}")
    spec = ROBOT_SPECS[robot]
    door_m = max(kind.door_m, snap(spec.width_m + JAMB_M + 0.05, 0.1))  # robot width + 0.3 m at least
    types = room_types_for(kind, rooms)
    plan = plan_floor(
        kind.layout,
        size,
        types,
        min_room_m=kind.min_room_m,
        door_m=door_m,
        corridor_m=kind.corridor_m,
        size_ranks={key: ROOM_TYPES[key].size_rank for key in types},
        rng=rng,
    )
    placed = furnish(plan, spec.radius_m, rng)
    objects, placement = _objects(plan, placed)
    name = f"{kind.name}-{request.seed}"
    described = ", ".join(ROOM_TYPES[r.type_key].label for r in plan.rooms)
    data: dict[str, Any] = {
        "name": name,
        "description": f"Generated {kind.name} (seed {request.seed}): {described}; {len(placed)} objects.",
        "robot": robot,
        "bounds": {"x": [0.0, size[0]], "y": [0.0, size[1]]},
        "floor_color": [0.55, 0.55, 0.5, 1.0],
        "wall_height": WALL_HEIGHT_M,
        "sensors": SENSORS,
        "walls": _walls(plan),
        "objects": objects,
    }
    bare = Scenario.model_validate(data)  # the world without tasks (no default start yet to check)
    tasks = make_tasks(bare, plan, placement, rng, request.starts)
    poses = [t["start_poses"][0] for t in tasks if t["kind"] != "target"] + [t["start_poses"][0] for t in tasks]
    if not poses:
        raise BadInputError(
            f"a {size[0]:g} m x {size[1]:g} m {kind.name} of {rooms} rooms leaves the robot no room to start"
        )
    data["default_start"] = poses[0]
    data["tasks"] = tasks
    scenario = parse_scenario(data, name)
    header = [
        f"{name}: a generated {kind.name} ({size[0]:g} m x {size[1]:g} m, {rooms} rooms, {len(plan.doors)} doorways).",
        f"Made by: llmnav scenarios generate --kind {kind.name} --seed {request.seed} --rooms {rooms} "
        f"--size {size[0]:g}x{size[1]:g} --starts {request.starts} --robot {robot} (generator version "
        f"{GENERATOR_VERSION}); the same command writes the same bytes.",
        "Rooms are labelled floor patches (room-N); furniture ids are catalogue key-N; aliases are synonyms of",
        "the label, never a task's wording. Start poses lie outside every target's room, clear of everything",
        "solid, with a target reachable and none in line of sight (llmnav scenarios check).",
    ]
    return Building(scenario, to_yaml(data, header))


def generate_suite(request: Request, count: int) -> list[Building]:
    """`count` buildings of seeds `request.seed`, `request.seed + 1`, ... (all made before any is returned)."""
    if not 1 <= count <= MAX_SUITE:
        raise BadInputError(f"--count {count}: a suite holds 1 to {MAX_SUITE} buildings")
    return [generate(replace(request, seed=request.seed + k)) for k in range(count)]
