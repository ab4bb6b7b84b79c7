"""Point-to-point shortest paths on a scenario's occupancy grid, for planners that need one leg at a time.

A thin layer over `astar`: snap both ends to free cells, search, shortcut by line of sight, and return
world points. Used by the hybrid planner (executing a chosen option) and the FSM (L_opt of the
trajectory efficiency eta).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from llmnav.core.geometry import Point, path_length
from llmnav.mapping.astar import astar, shortcut
from llmnav.mapping.grid import nearest_free_cell
from llmnav.mapping.targets import scenario_grid

if TYPE_CHECKING:
    from llmnav.mapping.grid import OccupancyGrid
    from llmnav.world.scenario import Scenario

SNAP_M = 0.5  # [m] how far an end point may move to the nearest free cell (a pose inside the inflation)


def plan_path(grid: OccupancyGrid, start: Point, goal: Point) -> list[Point] | None:
    """Shortcut polyline [m] from start to goal (start and goal included), None when unreachable."""
    geometry = grid.geometry
    start_cell = nearest_free_cell(grid.blocked, geometry, start[0], start[1], SNAP_M)
    goal_cell = nearest_free_cell(grid.blocked, geometry, goal[0], goal[1], SNAP_M)
    if start_cell is None or goal_cell is None:
        return None
    path = astar(grid.blocked, start_cell, goal_cell, resolution_m=geometry.resolution)
    if path is None:
        return None
    corners = [geometry.cell_to_world(*cell) for cell in shortcut(path.cells, grid.blocked)]
    return [start, *corners[1:-1], goal] if len(corners) >= 2 else [start, goal]


def shortest_path_length(scenario: Scenario, start: Point, goal: Point) -> float | None:
    """Length [m] of the shortest collision-free path between two points of a scenario."""
    path = plan_path(scenario_grid(scenario), start, goal)
    return None if path is None else path_length(path)
