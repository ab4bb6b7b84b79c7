"""Shortest collision-free paths from a pose to a task's targets (the oracle's path, every run's yardstick).

It builds the true occupancy grid of the scenario (`grid.build_grid`, inflated by robot radius + margin)
and runs one A* (`astar.astar`) from the start cell to the union of every acceptable target's *approach
cells*:

- an object target: free cells whose centre lies 1.5–2.5 m from the object's goal point (the distance at
  which the stepwise source asks the robot to stop, and at which the score's distance term is 1), shrunk
  by 0.1 m on both sides so the robot's stop tolerance cannot carry it out of the band;
- a point target (T4's free spot between the stairs and the barrels): the point's own cell when free,
  otherwise the same band around it.

The heuristic is the octile distance to the nearest target's goal point minus that target's outer radius
(stretched to octile), a lower bound of the remaining cost, so the first approach cell A* settles is the
nearest by path length.

Reported length: `OraclePath.length_m` (what `oracle_length` and the metric `oracle_length_m` give) is
the length of the line-of-sight shortcut of the A* path, itself a collision-free path on the inflated
grid, and the one the oracle drives. The raw 8-connected grid length (`grid_length_m`, metric
`oracle_grid_length_m`) is kept beside it: it overstates the true shortest path by up to ~8 % (grid
zig-zags), so with it the oracle's own drives would come out *shorter* than the "shortest" path.

Reference: Hart, Nilsson, Raphael (1968), see `astar.py`.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from functools import lru_cache
from typing import TYPE_CHECKING

import numpy as np

from llmnav.core.geometry import Point, Pose2D, path_length
from llmnav.errors import BadInputError
from llmnav.mapping.astar import GridPath, astar, densify, line_of_sight, shortcut
from llmnav.mapping.grid import Cell, GridConfig, OccupancyGrid, build_grid, nearest_free_cell

if TYPE_CHECKING:
    from llmnav.world.scenario import Scenario, Target, Task

SQRT2 = math.sqrt(2.0)
OCTILE_STRETCH = math.sqrt(4.0 - 2.0 * SQRT2)  # max octile / Euclidean ratio (at 22.5 deg), ~1.082


@dataclass(frozen=True)
class OracleConfig:
    """Where the oracle may stop and how its path is driven."""

    approach_min_m: float = 1.5  # [m] closest acceptable distance to a target's goal point
    approach_max_m: float = 2.5  # [m] farthest acceptable distance (the score's full-distance radius)
    band_slack_m: float = 0.1  # [m] the planned band is shrunk by this on both sides so the driven stop
    # (within final_tol_m of the approach point) still lies inside the acceptable band
    start_snap_m: float = 0.5  # [m] a start inside the inflation may step this far to the nearest free cell
    waypoint_spacing_m: float = 2.0  # [m] longest straight leg handed to go_to (keeps legs short and logged)
    # [m] go_to tolerance at intermediate waypoints: a leg starts up to this far off its planned corner and
    # so can lose that much of the grid's margin; the leg check needs 0.02 m of the 0.10 (0.1 here let
    # legs past a cylinder be refused)
    waypoint_tol_m: float = 0.05
    final_tol_m: float = 0.05  # [m] tolerance at the approach point (stay inside the band)
    grid: GridConfig = field(default_factory=GridConfig)


@dataclass(frozen=True)
class OraclePath:
    """A shortest path to one target's approach point."""

    target: Target
    target_point: Point  # [m] what the robot finally faces: the object itself, or a point target
    approach: Point  # [m] where the path ends
    cells: list[Cell]
    points: list[Point]  # [m] the shortcut polyline: start pose, corners, approach point
    grid_points: list[Point]  # [m] the raw grid path: start pose, then cell centres
    waypoints: list[Point]  # [m] `points` densified for go_to; excludes the start, ends at `approach`
    length_m: float  # [m] length of `points` (the value reported)
    grid_length_m: float  # [m] length of `grid_points` (raw 8-connected length)


@dataclass(frozen=True)
class _Goal:
    """One target's approach cells and the radius used by the heuristic."""

    target: Target
    point: Point
    mask: np.ndarray
    reach_m: float  # [m] every goal cell centre lies within this of `point`
    face: Point | None = None  # [m] what to face on arrival when it is not `point`


def _approach_goal(
    grid: OccupancyGrid, target: Target, point: Point, config: OracleConfig, *, exact: bool = False
) -> _Goal:
    """Where the oracle may stop for one target.

    The point itself when it is a stand point (a point target, or a corridor world's room plate with its
    `goal`), else the 1.5–2.5 m band around it.
    """
    geometry = grid.geometry
    if (exact or target.point is not None) and grid.is_free(*point):
        mask = np.zeros(geometry.shape, dtype=bool)
        mask[geometry.world_to_cell(*point)] = True
        return _Goal(target, point, mask, geometry.resolution * math.sqrt(0.5))
    xs, ys = geometry.centres()
    distance = np.hypot(xs - point[0], ys - point[1])
    low, high = config.approach_min_m + config.band_slack_m, config.approach_max_m - config.band_slack_m
    mask = (distance >= low) & (distance <= high) & ~grid.blocked
    return _Goal(target, point, mask, high)


@dataclass(frozen=True)
class _Region:
    """Cells to reach around a point, and the radius the heuristic needs."""

    point: Point
    mask: np.ndarray
    reach_m: float  # [m] every cell centre of `mask` lies within this of `point`


def _search(
    grid: OccupancyGrid, goals: Sequence[_Goal | _Region], start: Point, snap_m: float
) -> tuple[GridPath, int] | None:
    """A* from `start` (snapped up to `snap_m` [m] to a free cell) to the union of the goals' cells.

    Returns the grid path and the index of the goal it reached.
    """
    geometry = grid.geometry
    union = np.zeros(geometry.shape, dtype=bool)
    for goal in goals:
        union |= goal.mask
    start_cell = nearest_free_cell(grid.blocked, geometry, start[0], start[1], snap_m)
    if start_cell is None or not union.any():
        return None
    # Octile distance is a norm at most OCTILE_STRETCH times the Euclidean one, so octile(cell, point) minus
    # OCTILE_STRETCH x reach never overestimates the cost to any goal cell within `reach` of the point.
    xs, ys = geometry.centres()
    heuristic = np.full(geometry.shape, np.inf)
    for goal in goals:
        dx, dy = np.abs(xs - goal.point[0]), np.abs(ys - goal.point[1])
        octile = np.maximum(dx, dy) + (SQRT2 - 1.0) * np.minimum(dx, dy)
        heuristic = np.minimum(heuristic, octile - OCTILE_STRETCH * goal.reach_m)
    heuristic = np.maximum(heuristic, 0.0)
    path = astar(grid.blocked, start_cell, union, resolution_m=geometry.resolution, heuristic=heuristic)
    if path is None:
        return None
    return path, next(i for i, g in enumerate(goals) if g.mask[path.goal])


def plan_to_targets(
    grid: OccupancyGrid,
    scenario: Scenario,
    targets: Sequence[Target],
    start: Point,
    config: OracleConfig | None = None,
) -> OraclePath | None:
    """Shortest path on `grid` from `start` to the nearest approach cell of any target (None: unreachable)."""
    config = config or OracleConfig()
    geometry = grid.geometry
    goals = []
    for target in targets:
        point = scenario.object(target.object).goal_point if target.object is not None else target.point
        assert point is not None
        # In corridor worlds (source B) an object's `goal` is a stand point the robot must reach exactly.
        obj = scenario.object(target.object) if target.object is not None else None
        exact = bool(scenario.corridors) and obj is not None and obj.goal is not None
        goal = _approach_goal(grid, target, (float(point[0]), float(point[1])), config, exact=exact)
        if exact:  # standing on the stand point, face the object (a plate on the wall), not the point
            goal = replace(goal, face=scenario.object(target.object or "").center)
        goals.append(goal)
    found = _search(grid, goals, start, config.start_snap_m)
    if found is None:
        return None
    path, index = found
    goal = goals[index]
    centres = [geometry.cell_to_world(*cell) for cell in path.cells]
    # The exact start pose replaces its cell's centre; a path of one cell still steps to that centre.
    grid_points = [(start[0], start[1]), *(centres[1:] if len(centres) > 1 else centres)]
    corners = [geometry.cell_to_world(*cell) for cell in shortcut(path.cells, grid.blocked)]
    points = [(start[0], start[1]), *(corners[1:] if len(corners) > 1 else corners)]
    waypoints = densify(points, config.waypoint_spacing_m)[1:]
    return OraclePath(
        target=goal.target,
        target_point=goal.face or goal.point,
        approach=centres[-1],
        cells=path.cells,
        points=points,
        grid_points=grid_points,
        waypoints=waypoints,
        length_m=path_length(points),
        grid_length_m=path_length(grid_points),
    )


@dataclass(frozen=True, eq=True)
class _ScenarioKey:
    """Hashable handle of a (frozen, but list-holding) Scenario for caches: equal content, equal key."""

    digest: str
    scenario: Scenario = field(compare=False, hash=False)

    @classmethod
    def of(cls, scenario: Scenario) -> _ScenarioKey:
        return cls(hashlib.sha256(scenario.model_dump_json().encode()).hexdigest(), scenario)


@lru_cache(maxsize=8)
def _grid_for(key: _ScenarioKey, config: GridConfig) -> OccupancyGrid:
    return build_grid(key.scenario, config=config)


def scenario_grid(scenario: Scenario, config: GridConfig | None = None) -> OccupancyGrid:
    """The true inflated grid of a scenario (cached by content: do not modify the returned arrays)."""
    return _grid_for(_ScenarioKey.of(scenario), config or GridConfig())


def with_added_obstacles(
    scenario: Scenario, centres: Sequence[Point], size_m: float = 0.5, *, prefix: str = "added"
) -> Scenario:
    """The scenario plus the boxes `llmnav drive --obstacle` drops (size [m] as `World.add_obstacle`).

    `prefix` names them (`prefix:1`, ...): planners that mark what blocked them use their own.
    """
    # deferred: pydantic and yaml (about 0.15 s, via llmnav.world.scenario) only when obstacles are added
    from llmnav.world.scenario import Obstacle

    if not centres:
        return scenario
    first = 1 + sum(1 for o in scenario.obstacles if (o.id or "").startswith(f"{prefix}:"))
    added = [
        Obstacle(id=f"{prefix}:{i}", center=(float(x), float(y)), size=(size_m, size_m))
        for i, (x, y) in enumerate(centres, start=first)
    ]
    return scenario.model_copy(update={"obstacles": [*scenario.obstacles, *added]})


def oracle_path(
    scenario: Scenario, task: Task, start: Pose2D, *, config: OracleConfig | None = None
) -> OraclePath | None:
    """A* from `start` to the nearest acceptable approach point; None if unreachable or without targets."""
    config = config or OracleConfig()
    if not task.targets:
        return None
    grid = scenario_grid(scenario, config.grid)
    return plan_to_targets(grid, scenario, task.targets, (start.x, start.y), config)


@lru_cache(maxsize=1024)
def _cached_length(key: _ScenarioKey, task_json: str, x: float, y: float) -> float | None:
    # deferred: pydantic and yaml (about 0.15 s, via llmnav.world.scenario) only when a length is computed
    from llmnav.world.scenario import Task

    # keyed by the task's content, not its id: free-text tasks share one id and differ in their targets
    path = oracle_path(key.scenario, Task.model_validate_json(task_json), Pose2D(x, y, 0.0))
    return None if path is None else path.length_m


def oracle_length(scenario: Scenario, task: Task | str, start_pose_index_or_pose: int | Pose2D) -> float | None:
    """The oracle's path length [m] (`OraclePath.length_m`), cached; None without targets or path.

    An int is a 1-based index into the task's start poses (as `llmnav drive --start-pose`); a Pose2D is
    used as is.
    """
    task_obj = scenario.task(task) if isinstance(task, str) else task
    if isinstance(start_pose_index_or_pose, Pose2D):
        pose = start_pose_index_or_pose
    else:
        poses = scenario.start_poses(task_obj)
        index = int(start_pose_index_or_pose)
        if not 1 <= index <= len(poses):
            raise BadInputError(f"start pose {index} of task {task_obj.id} does not exist (1-based, 1..{len(poses)})")
        pose = poses[index - 1].pose()
    if not task_obj.targets:
        return None
    task_json = task_obj.model_copy(update={"start_poses": [], "paraphrases": []}).model_dump_json()
    return _cached_length(_ScenarioKey.of(scenario), task_json, round(pose.x, 6), round(pose.y, 6))


# For scoring: the robot's own footprint and nothing more, so no driven path can be shorter than this one.
SCORING_GRID = GridConfig(margin_m=0.0)


def goal_distance(
    scenario: Scenario,
    points: Sequence[Point],
    start: Point,
    radius_m: float,
    *,
    config: GridConfig = SCORING_GRID,
    snap_m: float = 0.5,
) -> float | None:
    """Shortest collision-free path length [m] from `start` to within `radius_m` of any of `points`.

    The oracle's geometry: A* on the scenario's true grid inflated by the robot radius (`config`: no extra
    margin by default), to every free cell whose centre lies within `radius_m` of a point, then the
    line-of-sight shortcut of that path pulled taut (`_taut_length`). 0 when `start` is already within the
    radius of a point; None when no point is given, a coordinate is not finite, `start` lies off the grid or
    deeper than `snap_m` [m] inside an obstacle's inflation, or no path exists. Cached per scenario content,
    points, start and radius.
    """
    if not points or not all(math.isfinite(v) for v in (*start, *(c for point in points for c in point), radius_m)):
        return None
    if any(math.hypot(start[0] - x, start[1] - y) <= radius_m for x, y in points):
        return 0.0
    key = (round(start[0], 6), round(start[1], 6))
    rounded = tuple((round(x, 6), round(y, 6)) for x, y in points)
    return _cached_goal_distance(_ScenarioKey.of(scenario), rounded, key, float(radius_m), config, float(snap_m))


@lru_cache(maxsize=4096)
def _cached_goal_distance(
    key: _ScenarioKey,
    points: tuple[Point, ...],
    start: Point,
    radius_m: float,
    config: GridConfig,
    snap_m: float,
) -> float | None:
    grid = _grid_for(key, config)
    straight = [math.dist(start, point) - radius_m for point in points]  # [m] a lower bound for each point
    start_cell = grid.geometry.world_to_cell(*start)
    clear = [
        gap
        for gap, point in zip(straight, points, strict=True)
        if _clear_to_radius(grid, start_cell, start, point, radius_m)
    ]
    if clear and min(clear) <= min(straight) + 1e-9:  # in sight and no other point can be nearer: no search
        return min(clear)
    xs, ys = grid.geometry.centres()
    regions = [
        _Region(point, (np.hypot(xs - point[0], ys - point[1]) <= radius_m) & ~grid.blocked, radius_m)
        for point in points
    ]
    found = _search(grid, regions, start, snap_m)
    if found is None:
        return None
    return _taut_length(grid, found[0].cells, start, points, radius_m)


def _clear_to_radius(grid: OccupancyGrid, cell: Cell, start: Point, point: Point, radius_m: float) -> bool:
    """Whether the straight line from `start` toward `point` is free until `radius_m` [m] from it."""
    if not grid.geometry.contains(cell) or grid.blocked[cell]:
        return False
    gap = math.dist(start, point) - radius_m
    t = gap / (gap + radius_m)
    entry = grid.geometry.world_to_cell(start[0] + (point[0] - start[0]) * t, start[1] + (point[1] - start[1]) * t)
    return grid.geometry.contains(entry) and line_of_sight(grid.blocked, cell, entry)


def _taut_length(
    grid: OccupancyGrid, cells: Sequence[Cell], start: Point, points: Sequence[Point], radius_m: float
) -> float:
    """The length [m] of an A* path pulled taut, ending where it first may: within `radius_m` of a point.

    The greedy shortcut keeps grid corners where the taut string would bend a little earlier, and the
    8-connected search picks its end cell by grid cost (a diagonal approach to the circle), both a few
    percent long. So: (1) each kept corner moves to the path cell between its neighbours that makes the
    two legs shortest with line of sight (a few passes), and (2) the path may leave at any kept point
    straight toward a point until the radius, when that leg is clear.
    """
    blocked, geometry = grid.blocked, grid.geometry
    where: list[Point] = [start, *(geometry.cell_to_world(*cell) for cell in cells[1:])]
    index = {cell: i for i, cell in enumerate(cells)}
    keep = [index[cell] for cell in shortcut(list(cells), blocked)]

    def leg(i: int, j: int) -> float:
        return math.dist(where[i], where[j])

    for _ in range(4):  # corner refinement; each pass only shortens, so it settles
        moved = False
        for k in range(1, len(keep) - 1):
            a, b = keep[k - 1], keep[k + 1]
            for m in sorted(range(a + 1, b), key=lambda m: leg(a, m) + leg(m, b)):
                if leg(a, m) + leg(m, b) >= leg(a, keep[k]) + leg(keep[k], b) - 1e-9:
                    break
                if line_of_sight(blocked, cells[a], cells[m]) and line_of_sight(blocked, cells[m], cells[b]):
                    keep[k], moved = m, True
                    break
        if not moved:
            break
    travelled = 0.0
    best = path_length([where[i] for i in keep])
    for k, i in enumerate(keep):
        travelled += leg(keep[k - 1], i) if k else 0.0
        for point in points:  # leave here straight toward the point, stop at the radius
            gap = math.dist(where[i], point) - radius_m
            if gap <= 0 or travelled + gap >= best:
                continue
            if _clear_to_radius(grid, cells[i], where[i], point, radius_m):
                best = travelled + gap
    return best
