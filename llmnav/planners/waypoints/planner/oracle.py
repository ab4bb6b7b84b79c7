"""The waypoint planner's oracle answers: the plan a perfect model would write, from ground truth.

A plan request is answered from the robot's true pose (a replan after an obstacle stop asks again from
wherever the robot stands) to the true target of the requested leg, keeping every rule of the source
(`validate.PlanRules`, the guard's bounds, judges each candidate, so the rules are the planner's own):

- corridor changes only through the labelled junction points: a shortest path over the graph of start,
  junction points and target, where a leg joins two points of one corridor (so no segment cuts a wall)
  and every leg is itself a valid one-point plan (the far end inside the corridor with the margin, the
  segment clear of the inflated true map and of the obstacles the request reports);
- spacing: every leg but the last is at least the spacing long;
- at most the environment's number of points, the last one exactly on the target;
- every segment keeps the robot's centre beyond the controller's emergency-stop distance from everything
  solid (the true map, with any `--obstacle` box): a plan the guard accepts but that passes a box closer
  than that is stopped every time it is driven, and its replans end the same way.

When obstacles close the junction route, the shortest grid path through the corridors (shrunk by the
margin, with the reported obstacles cleared by their stated distance) is cut into corners instead: from
each corner the farthest point of the path in sight, and from the start the farthest one at least the
spacing away (a robot stopped beside an obstacle would otherwise aim its first corner too close).
Grounding requests (free text naming no single object) are answered with the leg's true target, by its
id (a pick) or by scores (its label 0, every other label -10 nats; the content-free prefix all 0).
"""

from __future__ import annotations

import heapq
import json
import math
import re
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from llmnav.core.geometry import Point
from llmnav.core.robot_specs import ROBOT_SPECS
from llmnav.mapping.astar import astar, line_of_sight
from llmnav.mapping.grid import GridConfig, build_grid, nearest_free_cell
from llmnav.planners.waypoints.planner.validate import PlanRules
from llmnav.world.tasks import sequence_legs

if TYPE_CHECKING:
    from llmnav.core.chat import ChatRequest, ScoreRequest
    from llmnav.mapping.grid import OccupancyGrid
    from llmnav.planners.base import GroundTruth
    from llmnav.world.scenario import Scenario, Task

_NUMBER = r"(-?\d+(?:\.\d+)?)"
_TARGET = re.compile(rf'Target "[^"]*": x = {_NUMBER}, y = {_NUMBER}')
_OBSTACLES = re.compile(r"Obstacles reported on the way so far: (.*)")
_PAIR = re.compile(rf"\({_NUMBER}, {_NUMBER}\)")
_CLEARANCE = re.compile(rf"at least {_NUMBER} m from each")
_COMMAND = re.compile(r'Command: "(.*)"')
OTHER_LOGPROB = -10.0  # [nats] a label that is not the target's


@dataclass(frozen=True)
class WaypointOracleConfig:
    """How the oracle keeps clear of what the request reports."""

    # The request prints obstacle centres to 0.01 m; the guard checks the unrounded ones.
    obstacle_slack_m: float = 0.05  # [m]
    clear_slack_m: float = 0.05  # [m] kept beyond `keep_clear_m` (the controller's path is not a line)


@dataclass
class WaypointAnswerKey:
    """The `AnswerKey` of one waypoint episode (see the module docstring)."""

    truth: GroundTruth
    keep_clear_m: float  # [m] the robot centre stays this far from anything solid (the emergency stop)
    config: WaypointOracleConfig = field(default_factory=WaypointOracleConfig)
    _grid: OccupancyGrid | None = None

    @property
    def can_score(self) -> bool:
        """Grounding by scores is answered (see `scores`)."""
        return True

    @property
    def grid(self) -> OccupancyGrid:
        """The true map (with any `--obstacle` box), inflated to `keep_clear_m` (and the slack)."""
        if self._grid is None:
            scenario = self.truth.scenario
            # build_grid inflates by the robot radius plus the margin: make the sum the distance to keep
            margin = self.keep_clear_m + self.config.clear_slack_m - ROBOT_SPECS[scenario.robot].radius_m
            self._grid = build_grid(scenario, config=GridConfig(margin_m=max(margin, GridConfig().margin_m)))
        return self._grid

    def answer(self, request: ChatRequest) -> str:
        """A waypoint plan (JSON array) or, to a grounding request, the true target's id."""
        schema = request.json_schema or {}
        if schema.get("type") == "array":
            return json.dumps([{"x": round(x, 3), "y": round(y, 3)} for x, y in self.plan_for(request)])
        ids = schema.get("properties", {}).get("object_id", {}).get("enum", [])
        return json.dumps({"object_id": self._target_id(_text(request), ids)})

    def scores(self, request: ScoreRequest) -> tuple[float, ...]:
        """0 for the leg's true target label and `OTHER_LOGPROB` for the rest; all 0 without the command."""
        leg = self._leg(request.prefix)
        if leg is None:  # the content-free prefix: no label is likelier than another
            return tuple(0.0 for _ in request.continuations)
        scenario = self.truth.scenario
        names = {n for t in leg.targets if t.object for n in scenario.object(t.object).names()}
        return tuple(0.0 if c.strip().lower() in names else OTHER_LOGPROB for c in request.continuations)

    # --- plans ---------------------------------------------------------------------------------------
    def plan_for(self, request: ChatRequest) -> list[Point]:
        """The plan answering `request`: from the true pose to the true target nearest the requested one."""
        text = _text(request)
        pose = self.truth.pose()
        start = (pose.x, pose.y)
        target = self._true_target(text)
        obstacles, clearance = _reported_obstacles(text)
        return best_plan(
            self.truth.scenario, self.grid, start, target, obstacles, clearance + self.config.obstacle_slack_m
        )

    def _true_target(self, text: str) -> Point:
        """The acceptable target point (of any leg) nearest the one the request names."""
        points = [
            (float(x), float(y))
            for leg in sequence_legs(self.truth.scenario, self.truth.task)
            for x, y in self.truth.scenario.target_points(leg)
        ]
        found = _TARGET.search(text)
        if found is None or not points:
            raise ValueError("the waypoint request names no target, or the task has none")
        asked = (float(found.group(1)), float(found.group(2)))
        return min(points, key=lambda p: math.dist(p, asked))

    # --- grounding -----------------------------------------------------------------------------------
    def _leg(self, text: str) -> Task | None:
        """The leg whose command `text` quotes (longest first: one command may contain another)."""
        legs = sequence_legs(self.truth.scenario, self.truth.task)
        quoted = [leg for leg in legs if leg.text.strip() and leg.text.strip().lower() in text.lower()]
        return max(quoted, key=lambda leg: len(leg.text), default=None)

    def _target_id(self, text: str, ids: list[str]) -> str:
        """The listed id of the commanded leg's acceptable target nearest the robot (else the first listed)."""
        found = _COMMAND.search(text)
        leg = self._leg(found.group(1) if found else text)
        pose = self.truth.pose()
        objects = [self.truth.scenario.object(t.object) for t in (leg.targets if leg else []) if t.object]
        listed = [o for o in objects if o.id in ids]
        if not listed:
            return ids[0] if ids else ""
        return min(listed, key=lambda o: pose.distance_to(*o.goal_point)).id


def best_plan(
    scenario: Scenario,
    grid: OccupancyGrid,
    start: Point,
    target: Point,
    obstacles: list[Point],
    clearance_m: float,
) -> list[Point]:
    """The shortest valid plan through junction points, else a shortcut grid path (see the module docstring).

    Returns the junction plan even when invalid if neither is valid: the guard then says why.
    """
    plan = junction_plan(scenario, grid, start, target, obstacles, clearance_m)
    if plan is not None and not _problems(scenario, grid, start, target, plan, obstacles, clearance_m):
        return plan
    fallback = grid_plan(scenario, grid, start, target, obstacles, clearance_m)
    if fallback is not None and not _problems(scenario, grid, start, target, fallback, obstacles, clearance_m):
        return fallback
    return plan or fallback or [target]


def _problems(
    scenario: Scenario,
    grid: OccupancyGrid,
    start: Point,
    target: Point,
    points: list[Point],
    obstacles: list[Point],
    clearance_m: float,
) -> list[str]:
    """The planner's own rules on `points`: the bounds its guard applies to a model's plan (`PlanRules`)."""
    return PlanRules(scenario, start, target, grid, obstacles, clearance_m).problems(points)


def junction_plan(
    scenario: Scenario,
    grid: OccupancyGrid,
    start: Point,
    target: Point,
    obstacles: list[Point],
    clearance_m: float,
) -> list[Point] | None:
    """Shortest path start -> junction points -> target (Dijkstra), without the start; None if none."""
    rules = scenario.waypoint_rules
    junctions = [(float(o.center[0]), float(o.center[1])) for o in scenario.objects if "junction" in o.label.lower()]
    nodes: list[Point] = [start, *junctions, target]
    goal = len(nodes) - 1

    def joined(u: int, v: int) -> bool:
        a, b = nodes[u], nodes[v]
        # one corridor holds both ends (the far one with the margin), so the leg crosses no wall
        same = any(c.contains(*a) and c.contains(*b, rules.margin_m) for c in scenario.corridors)
        spaced = v == goal or math.dist(a, b) >= rules.spacing_m
        # a one-point plan a -> b: b inside with the margin, the segment clear of the map and obstacles
        return same and spaced and not _problems(scenario, grid, a, b, [b], obstacles, clearance_m)

    best = {0: 0.0}
    previous: dict[int, int] = {}
    queue = [(0.0, 0)]
    while queue:
        length, u = heapq.heappop(queue)
        if u == goal:
            break
        if length > best.get(u, math.inf):
            continue
        for v in range(1, len(nodes)):
            if v == u or not joined(u, v):
                continue
            candidate = length + math.dist(nodes[u], nodes[v])
            if candidate < best.get(v, math.inf):
                best[v], previous[v] = candidate, u
                heapq.heappush(queue, (candidate, v))
    if goal not in previous:
        return None
    path = [goal]
    while path[-1] != 0:
        path.append(previous[path[-1]])
    return [nodes[i] for i in reversed(path[:-1])]


def grid_plan(
    scenario: Scenario,
    grid: OccupancyGrid,
    start: Point,
    target: Point,
    obstacles: list[Point],
    clearance_m: float,
) -> list[Point] | None:
    """Corners of the shortest grid path inside the margin-shrunk corridors, clear of the obstacles."""
    geometry, rules = grid.geometry, scenario.waypoint_rules
    xs, ys = geometry.centres()
    inside = np.zeros(geometry.shape, dtype=bool)
    for c in scenario.corridors:
        inside |= (
            (xs >= c.x[0] + rules.margin_m)
            & (xs <= c.x[1] - rules.margin_m)
            & (ys >= c.y[0] + rules.margin_m)
            & (ys <= c.y[1] - rules.margin_m)
        )
    blocked = grid.blocked | ~inside
    for ox, oy in obstacles:
        blocked |= np.hypot(xs - ox, ys - oy) < clearance_m
    # the start may stand outside the shrunk corridors (a stop near a wall): snap it like `plan_path` does
    first = nearest_free_cell(blocked, geometry, start[0], start[1], rules.margin_m + 0.5)
    last = nearest_free_cell(blocked, geometry, target[0], target[1], rules.target_tolerance_m)
    if first is None or last is None:
        return None
    path = astar(blocked, first, last, resolution_m=geometry.resolution)
    if path is None:
        return None
    cells, points = path.cells, []
    here, at = start, 0
    while at < len(cells) - 1:
        in_sight = [j for j in range(len(cells) - 1, at, -1) if line_of_sight(blocked, cells[at], cells[j])]
        if not in_sight:  # the snapped start cell touches a blocked one
            return None
        far = [j for j in in_sight if math.dist(here, geometry.cell_to_world(*cells[j])) >= rules.spacing_m]
        spaced = [j for j in in_sight if j == len(cells) - 1 or j in far]
        at = (spaced or in_sight)[0]
        here = geometry.cell_to_world(*cells[at])
        points.append(here)
    return [*points[:-1], target]


def _reported_obstacles(text: str) -> tuple[list[Point], float]:
    """The obstacle centres a (re)plan request reports, and the clearance [m] it asks for (0 if none)."""
    line = _OBSTACLES.search(text)
    if line is None:
        return [], 0.0
    centres = [(float(x), float(y)) for x, y in _PAIR.findall(line.group(1))]
    clearance = _CLEARANCE.search(line.group(1))
    return centres, float(clearance.group(1)) if clearance else 0.0


def _text(request: ChatRequest) -> str:
    """Every message of the request, joined (the map facts are in the system turn, the command in a user turn)."""
    return "\n".join(m.text for m in request.messages)
