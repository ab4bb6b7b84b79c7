"""Tasks of a generated building and their start poses.

Kinds of task, each worded from templates that name only what the catalogue gives (labels, aliases, uses):

- an object by name ("Go to the sofa"; every object with that label is an acceptable target);
- an object by use ("Find somewhere to sit down"; every object whose catalogue item has that use);
- a room ("Go to the kitchen"; the room's floor, a labelled object, is the target);
- turn around once (a `rotate` task) and look around (an `explore` task).

Up to `starts` start poses are drawn in rooms that hold none of the task's targets, on a 0.05 m raster with
headings in 15 degree steps, and kept only when `check.Judge` passes them: clearance, a target reachable,
none within the success radius and none in line of sight in any direction. A task whose targets fill most
rooms may keep fewer; one for which no start pose is found is left out.
"""

from __future__ import annotations

import random
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from llmnav.buildings.catalogue import ITEMS_BY_KEY, USES
from llmnav.buildings.check import Judge
from llmnav.buildings.kinds import ROOM_TYPES
from llmnav.buildings.layout import FloorPlan, Room, snap
from llmnav.world.scenario import Scenario, Target, Task

START_TRIES = 400  # candidate poses drawn per task
START_SPACING_M = 1.0  # [m] two start poses of one task are at least this far apart
START_SLACK_M = 0.05  # [m] clearance beyond the checker's, so a start never sits on its limit
NAME_TASKS = 3
USE_TASKS = 2
ROOM_TASKS = 2

_NAME_WORDINGS = ("Go to the {n}", "Find the {n}", "Drive over to the {n}", "Take me to the {n}")
_ROOM_WORDINGS = ("Go to the {n}", "Take me to the {n}", "Head for the {n}", "Find your way to the {n}")
_ROTATE = (
    "Turn around on the spot once, a full circle",
    "Rotate all the way round where you stand",
    "Do one complete turn without moving off the spot",
)
_EXPLORE = ("Look around the room you are in", "Scan the room around you", "Get a view of everything around you")


@dataclass(frozen=True)
class Placement:
    """Where the labelled objects are and what they are.

    Object id -> room index, object id -> catalogue key, and room index -> the id of its floor.
    """

    room_of: dict[str, int]
    item_of: dict[str, str]
    room_ids: dict[int, str]


def _article(noun: str, several: bool) -> str:
    """'the sofa', or 'a sofa' / 'an armchair' when there are several."""
    if not several:
        return f"the {noun}"
    return f"{'an' if noun[0] in 'aeiou' else 'a'} {noun}"


def _worded(templates: tuple[str, ...], noun: str, several: bool) -> list[str]:
    return [t.replace("the {n}", _article(noun, several)) for t in templates]


class _Starts:
    """Draws start poses that the judge passes."""

    def __init__(self, scenario: Scenario, plan: FloorPlan, rng: random.Random) -> None:
        self.scenario = scenario
        self.plan = plan
        self.rng = rng
        self.judge = Judge(scenario)

    def draw(self, rooms: list[Room], count: int, accept: Callable[[float, float], bool]) -> list[dict[str, float]]:
        """Up to `count` poses in `rooms` passing the clearance test and `accept`."""
        poses: list[dict[str, float]] = []
        if not rooms:
            return poses
        margin = self.judge.clear_m + START_SLACK_M
        for _ in range(START_TRIES):
            if len(poses) == count:
                break
            area = self.rng.choice(rooms).inside.shrunk(margin)
            if area.width <= 0 or area.depth <= 0:
                continue
            x, y = snap(self.rng.uniform(area.x0, area.x1)), snap(self.rng.uniform(area.y0, area.y1))
            yaw = float(self.rng.randrange(-165, 181, 15))
            if any(((p["x"] - x) ** 2 + (p["y"] - y) ** 2) ** 0.5 < START_SPACING_M for p in poses):
                continue
            if self.judge.clearance(x, y) < margin or not accept(x, y):
                continue
            poses.append({"x": x, "y": y, "yaw_deg": yaw})
        return poses

    def for_targets(self, target_ids: list[str], placement: Placement, count: int) -> list[dict[str, float]]:
        """Poses outside every target's room, from which a target is reachable and none is seen."""
        task = Task(id="candidate", text="candidate", targets=[Target(object=i) for i in target_ids])
        regions = self.judge.target_regions(task)
        blocking = self.judge.blockers_for(set(target_ids))
        targets = [self.scenario.object(i) for i in target_ids]
        banned = {placement.room_of[i] for i in target_ids}
        rooms = [r for r in self.plan.rooms if r.index not in banned]

        def accept(x: float, y: float) -> bool:
            return self.judge.region(x, y) in regions and self.judge.sight_problem(x, y, targets, blocking) is None

        return self.draw(rooms, count, accept)


def make_tasks(
    scenario: Scenario, plan: FloorPlan, placement: Placement, rng: random.Random, starts: int
) -> list[dict[str, Any]]:
    """The building's tasks as scenario-file mappings, ids T1, T2, ... in the order of the kinds above."""
    sampler = _Starts(scenario, plan, rng)
    furniture = [o for o in scenario.objects if o.id not in placement.room_ids.values()]
    by_label: dict[str, list[str]] = {}
    for obj in furniture:
        by_label.setdefault(obj.label, []).append(obj.id)
    by_use: dict[str, list[str]] = {}
    for obj in furniture:
        for use in ITEMS_BY_KEY[placement.item_of[obj.id]].uses:
            by_use.setdefault(use, []).append(obj.id)
    by_room: dict[str, list[str]] = {}
    for room in plan.rooms:
        by_room.setdefault(room.type_key, []).append(placement.room_ids[room.index])

    drafts: list[tuple[str, str, list[str], list[str]]] = []  # (kind, difficulty, wordings, target ids)
    labels = sorted(by_label)
    rng.shuffle(labels)
    for label in labels[:NAME_TASKS]:
        ids = by_label[label]
        wordings = _worded(_NAME_WORDINGS, label, len(ids) > 1)
        aliases = scenario.object(ids[0]).aliases
        if aliases:  # a synonym, as people say it: "Find the couch" for a sofa
            wordings[-1] = f"Look for {_article(aliases[0], len(ids) > 1)}"
        drafts.append(("target", "easy" if len(ids) == 1 else "medium", wordings, ids))
    uses = sorted(by_use)
    rng.shuffle(uses)
    named = [sorted(d[3]) for d in drafts]
    uses = [u for u in uses if sorted(by_use[u]) not in named]  # "throw away rubbish" = "the waste bin": once
    for use in uses[:USE_TASKS]:
        drafts.append(("target", "hard", list(USES[use]), by_use[use]))
    room_keys = sorted(by_room)
    rng.shuffle(room_keys)
    for key in room_keys[:ROOM_TASKS]:
        ids = by_room[key]
        drafts.append(("target", "medium", _worded(_ROOM_WORDINGS, ROOM_TYPES[key].label, len(ids) > 1), ids))

    tasks: list[dict[str, Any]] = []
    for _, difficulty, wordings, ids in drafts:
        poses = sampler.for_targets(sorted(ids), placement, starts)
        if poses:
            tasks.append(_task(len(tasks) + 1, wordings, "target", difficulty, sorted(ids), poses))
    everywhere = list(plan.rooms)
    for kind, texts in (("rotate", _ROTATE), ("explore", _EXPLORE)):
        poses = sampler.draw(everywhere, starts, lambda x, y: True)
        if poses:
            tasks.append(_task(len(tasks) + 1, list(texts), kind, "easy", [], poses))
    return tasks


def _task(
    number: int, wordings: list[str], kind: str, difficulty: str, ids: list[str], poses: list[dict[str, float]]
) -> dict[str, Any]:
    task: dict[str, Any] = {
        "id": f"T{number}",
        "text": wordings[0],
        "paraphrases": wordings[1:],
        "kind": kind,
        "difficulty": difficulty,
    }
    if ids:
        task["targets"] = [{"object": i} for i in ids]
    task["start_poses"] = poses
    return task
