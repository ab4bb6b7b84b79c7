"""A* shortest paths on an 8-connected occupancy grid, line-of-sight shortcutting and waypoints.

Moves go to the 8 neighbours; a straight move costs one cell side, a diagonal √2 cell sides, and a
diagonal is allowed only when both cells it squeezes between are free (no corner cutting, so the
inflated robot never clips an obstacle's corner). With the octile heuristic — the exact cost on an empty
8-connected grid — A* returns a shortest grid path. The goal may be one cell or a set of cells (a mask);
for a set the caller passes an admissible heuristic array (0 turns A* into Dijkstra).

`shortcut` then removes grid zig-zags by line of sight on the same blocked mask; its result is still
collision-free and never longer. Which length to report is the caller's choice: `GridPath.length_m` is
the raw grid length (8-connected paths can be up to ≈ 8 % longer than the true Euclidean shortest path),
`polyline_length` of the shortcut corners is closer to it (the oracle reports that one).

Reference: P. E. Hart, N. J. Nilsson, B. Raphael, "A formal basis for the heuristic determination of
minimum cost paths", IEEE Trans. SSC 4(2), 1968.
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass

import numpy as np

from llmnav.errors import BadInputError

Cell = tuple[int, int]  # (row, col)

_SQRT2 = math.sqrt(2.0)


@dataclass(frozen=True)
class AStarConfig:
    """Search limits."""

    max_expansions: int = 5_000_000  # [cells] give up beyond this (a bug guard; a 20 m x 16 m grid has 130k)
    allow_blocked_start: bool = True  # expand the start even if blocked (the robot is already there)


@dataclass(frozen=True)
class GridPath:
    """A path of cells from start to goal (both included)."""

    cells: list[Cell]
    length_m: float  # [m] grid length: straight steps x resolution, diagonals x resolution x √2
    expanded: int  # cells taken off the open list (search effort)

    @property
    def goal(self) -> Cell:
        """The cell the path ends at."""
        return self.cells[-1]


def octile_distance(a: Cell, b: Cell, resolution_m: float) -> float:
    """Exact shortest distance [m] between two cells on an obstacle-free 8-connected grid."""
    d_row, d_col = abs(a[0] - b[0]), abs(a[1] - b[1])
    return resolution_m * (max(d_row, d_col) + (_SQRT2 - 1.0) * min(d_row, d_col))


def octile_field(shape: tuple[int, int], goal: Cell, resolution_m: float) -> np.ndarray:
    """`octile_distance` [m] from every cell of a grid to `goal` (the default A* heuristic)."""
    d_row = np.abs(np.arange(shape[0]) - goal[0])[:, None]
    d_col = np.abs(np.arange(shape[1]) - goal[1])[None, :]
    return np.asarray(resolution_m * (np.maximum(d_row, d_col) + (_SQRT2 - 1.0) * np.minimum(d_row, d_col)))


def astar(
    blocked: np.ndarray,
    start: Cell,
    goal: Cell | np.ndarray,
    *,
    resolution_m: float,
    heuristic: np.ndarray | None = None,
    config: AStarConfig | None = None,
) -> GridPath | None:
    """Shortest 8-connected path from `start` to `goal` (a cell, or a bool mask of acceptable cells).

    `heuristic` holds, per cell, a lower bound [m] of the cost to the nearest goal cell; it must be
    consistent (never drop by more than a move's cost) for the result to be optimal. Default: the octile
    distance to a single goal cell, zero (Dijkstra) for a mask.

    Returns None when no goal cell is reachable. Raises BadInputError for a start or goal outside the
    grid, and when `max_expansions` is exceeded.
    """
    config = config or AStarConfig()
    rows, cols = blocked.shape
    if not (0 <= start[0] < rows and 0 <= start[1] < cols):
        raise BadInputError(f"A* start cell {start} lies outside the {rows}x{cols} grid")
    if isinstance(goal, np.ndarray):
        if goal.shape != blocked.shape:
            raise BadInputError(f"A* goal mask shape {goal.shape} differs from the grid's {blocked.shape}")
        goal_mask = goal & ~blocked
        if heuristic is None:
            heuristic = np.zeros(blocked.shape)
    else:
        if not (0 <= goal[0] < rows and 0 <= goal[1] < cols):
            raise BadInputError(f"A* goal cell {goal} lies outside the {rows}x{cols} grid")
        goal_mask = np.zeros_like(blocked, dtype=bool)
        goal_mask[goal] = not blocked[goal]
        if heuristic is None:
            heuristic = octile_field(blocked.shape, goal, resolution_m)
    if heuristic.shape != blocked.shape:
        raise BadInputError(f"A* heuristic shape {heuristic.shape} differs from the grid's {blocked.shape}")
    if not goal_mask.any():
        return None
    if blocked[start] and not config.allow_blocked_start:
        return None

    # Work on flat indices of a grid padded with one blocked ring: no bounds checks in the inner loop.
    width = cols + 2
    wall = np.pad(blocked, 1, constant_values=True).ravel().tolist()
    is_goal = np.pad(goal_mask, 1, constant_values=False).ravel().tolist()
    estimate = np.pad(np.asarray(heuristic, dtype=float), 1).ravel().tolist()  # [m]
    straight = resolution_m
    diagonal = resolution_m * _SQRT2
    # (index offset, cost, the two orthogonal offsets a diagonal squeezes between or None)
    moves: list[tuple[int, float, tuple[int, int] | None]] = [
        (1, straight, None),
        (-1, straight, None),
        (width, straight, None),
        (-width, straight, None),
        (width + 1, diagonal, (width, 1)),
        (width - 1, diagonal, (width, -1)),
        (-width + 1, diagonal, (-width, 1)),
        (-width - 1, diagonal, (-width, -1)),
    ]

    start_index = (start[0] + 1) * width + (start[1] + 1)
    size = len(wall)
    cost = [math.inf] * size  # [m] best known cost from the start
    parent = [-1] * size
    closed = bytearray(size)
    cost[start_index] = 0.0
    tie = 0  # FIFO among equal f: keeps the search deterministic
    open_heap: list[tuple[float, int, int]] = [(estimate[start_index], tie, start_index)]
    expanded = 0
    while open_heap:
        _, _, index = heapq.heappop(open_heap)
        if closed[index]:
            continue
        closed[index] = 1
        expanded += 1
        if is_goal[index]:
            return GridPath(_trace(parent, index, width), cost[index], expanded)
        if expanded > config.max_expansions:
            raise BadInputError(f"A* gave up after {config.max_expansions} expansions")
        base = cost[index]
        for offset, step, squeeze in moves:
            neighbour = index + offset
            if wall[neighbour] or closed[neighbour]:
                continue
            if squeeze is not None and (wall[index + squeeze[0]] or wall[index + squeeze[1]]):
                continue
            new_cost = base + step
            if new_cost < cost[neighbour]:
                cost[neighbour] = new_cost
                parent[neighbour] = index
                tie += 1
                heapq.heappush(open_heap, (new_cost + estimate[neighbour], tie, neighbour))
    return None


def _trace(parent: list[int], index: int, width: int) -> list[Cell]:
    cells: list[Cell] = []
    while index != -1:
        row, col = divmod(index, width)
        cells.append((row - 1, col - 1))
        index = parent[index]
    cells.reverse()
    return cells


def line_of_sight(blocked: np.ndarray, a: Cell, b: Cell) -> bool:
    """Whether the straight segment between two cell centres crosses only free cells.

    Samples the segment every quarter cell and also checks both orthogonal neighbours a sample may
    straddle, so diagonal slips between two blocked cells are refused like in `astar`.
    """
    span = max(abs(b[0] - a[0]), abs(b[1] - a[1]))
    samples = np.linspace(0.0, 1.0, 4 * span + 2)
    row_f = a[0] + (b[0] - a[0]) * samples
    col_f = a[1] + (b[1] - a[1]) * samples
    # A point near a cell corner belongs to up to four cells; test all that it touches (±0.25 cell).
    eps = 0.25
    rows_lo = np.floor(row_f + 0.5 - eps).astype(np.int64)
    rows_hi = np.floor(row_f + 0.5 + eps).astype(np.int64)
    cols_lo = np.floor(col_f + 0.5 - eps).astype(np.int64)
    cols_hi = np.floor(col_f + 0.5 + eps).astype(np.int64)
    rows_all = np.concatenate([rows_lo, rows_lo, rows_hi, rows_hi])
    cols_all = np.concatenate([cols_lo, cols_hi, cols_lo, cols_hi])
    n_rows, n_cols = blocked.shape
    if rows_all.min() < 0 or cols_all.min() < 0 or rows_all.max() >= n_rows or cols_all.max() >= n_cols:
        return False
    return not bool(blocked[rows_all, cols_all].any())


def shortcut(cells: list[Cell], blocked: np.ndarray) -> list[Cell]:
    """Greedy line-of-sight shortcutting: keep a cell only where the line from the last kept one breaks.

    Every kept segment is clear by `line_of_sight` (a start inside the inflation simply keeps the
    path's first free cell too, since no line from a blocked cell is clear).
    """
    if len(cells) <= 2:
        return list(cells)
    kept = [cells[0]]
    for index in range(2, len(cells)):
        if not line_of_sight(blocked, kept[-1], cells[index]):
            kept.append(cells[index - 1])  # adjacent to cells[index]: the next segment is a grid step
    kept.append(cells[-1])
    return kept


def densify(points: list[tuple[float, float]], max_spacing_m: float) -> list[tuple[float, float]]:
    """Insert evenly spaced points so no segment is longer than `max_spacing_m` (first point kept)."""
    if max_spacing_m <= 0:
        raise BadInputError(f"waypoint spacing must be positive, got {max_spacing_m} m")
    if not points:
        return []
    out = [points[0]]
    for p, q in zip(points, points[1:], strict=False):
        pieces = max(1, math.ceil(math.dist(p, q) / max_spacing_m - 1e-9))
        for k in range(1, pieces + 1):
            t = k / pieces
            out.append((p[0] + (q[0] - p[0]) * t, p[1] + (q[1] - p[1]) * t))
    return out
