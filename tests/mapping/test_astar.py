"""A* on hand-made grids: optimal (against a brute-force Dijkstra), no corner cutting, unreachable."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.sparse import lil_matrix
from scipy.sparse.csgraph import dijkstra

from llmnav.core.geometry import path_length
from llmnav.errors import BadInputError
from llmnav.mapping.astar import astar, densify, line_of_sight, octile_distance, shortcut


def reference_distance(blocked: np.ndarray, start: tuple[int, int], goal: tuple[int, int]) -> float:
    """Brute force: every legal 8-connected move as a graph edge, scipy's Dijkstra over all of it."""
    rows, cols = blocked.shape
    graph = lil_matrix((rows * cols, rows * cols))
    for r in range(rows):
        for c in range(cols):
            if blocked[r, c]:
                continue
            for dr in (-1, 0, 1):
                for dc in (-1, 0, 1):
                    rr, cc = r + dr, c + dc
                    if (dr, dc) == (0, 0) or not (0 <= rr < rows and 0 <= cc < cols) or blocked[rr, cc]:
                        continue
                    if dr and dc and (blocked[r + dr, c] or blocked[r, c + dc]):
                        continue
                    graph[r * cols + c, rr * cols + cc] = math.sqrt(2) if dr and dc else 1.0
    dist = dijkstra(graph.tocsr(), indices=start[0] * cols + start[1])
    return float(dist[goal[0] * cols + goal[1]])


def path_is_legal(blocked: np.ndarray, cells: list[tuple[int, int]]) -> bool:
    for (r0, c0), (r1, c1) in zip(cells, cells[1:], strict=False):
        dr, dc = r1 - r0, c1 - c0
        if max(abs(dr), abs(dc)) != 1 or blocked[r1, c1]:
            return False
        if dr and dc and (blocked[r0 + dr, c0] or blocked[r0, c0 + dc]):
            return False
    return True


def test_known_value_around_a_wall() -> None:
    # 5x7 grid, a wall in column 3 from row 0 to row 3: the only way round is through row 4.
    blocked = np.zeros((5, 7), dtype=bool)
    blocked[0:4, 3] = True
    path = astar(blocked, (0, 0), (0, 6), resolution_m=0.5)
    assert path is not None
    # By hand: (0,0) -> (4,2) is 2 diagonals + 2 straight; (4,2) -> (4,4) 2 straight under the wall (the
    # diagonals (3,2)->(4,3) and (4,3)->(3,4) would cut the wall's corner (3,3)); (4,4) -> (0,6) 2 + 2 again.
    assert path.length_m == pytest.approx(0.5 * reference_distance(blocked, (0, 0), (0, 6)))
    assert path.length_m == pytest.approx(0.5 * (6 + 4 * math.sqrt(2)))
    assert path_is_legal(blocked, path.cells)
    assert path.cells[0] == (0, 0) and path.cells[-1] == (0, 6)


def test_empty_grid_equals_octile_distance() -> None:
    blocked = np.zeros((20, 30), dtype=bool)
    path = astar(blocked, (2, 3), (17, 25), resolution_m=0.05)
    assert path is not None
    assert path.length_m == pytest.approx(octile_distance((2, 3), (17, 25), 0.05))
    assert path.length_m == pytest.approx(0.05 * (15 * math.sqrt(2) + 7))


@pytest.mark.parametrize("seed", range(12))
def test_optimal_on_random_grids(seed: int) -> None:
    rng = np.random.default_rng(seed)
    blocked = rng.random((14, 18)) < 0.3
    start, goal = (0, 0), (13, 17)
    blocked[start] = blocked[goal] = False
    expected = reference_distance(blocked, start, goal)
    path = astar(blocked, start, goal, resolution_m=1.0)
    if not math.isfinite(expected):
        assert path is None
    else:
        assert path is not None
        assert path.length_m == pytest.approx(expected)
        assert path_is_legal(blocked, path.cells)


def test_no_corner_cutting() -> None:
    blocked = np.zeros((2, 2), dtype=bool)
    blocked[0, 1] = blocked[1, 0] = True  # the diagonal (0,0)->(1,1) squeezes between two blocked cells
    assert astar(blocked, (0, 0), (1, 1), resolution_m=1.0) is None
    blocked[1, 0] = False  # one free side: still no diagonal, go round the corner
    path = astar(blocked, (0, 0), (1, 1), resolution_m=1.0)
    assert path is not None and path.cells == [(0, 0), (1, 0), (1, 1)]
    assert path.length_m == pytest.approx(2.0)


def test_unreachable_and_blocked_goal() -> None:
    blocked = np.zeros((6, 6), dtype=bool)
    blocked[:, 3] = True
    assert astar(blocked, (0, 0), (5, 5), resolution_m=1.0) is None
    blocked[:, 3] = False
    blocked[5, 5] = True
    assert astar(blocked, (0, 0), (5, 5), resolution_m=1.0) is None
    with pytest.raises(BadInputError):
        astar(blocked, (0, 9), (1, 1), resolution_m=1.0)


def test_goal_set_reaches_the_nearest_cell() -> None:
    blocked = np.zeros((10, 10), dtype=bool)
    goals = np.zeros_like(blocked)
    goals[9, 9] = goals[0, 6] = True
    path = astar(blocked, (0, 0), goals, resolution_m=1.0)
    assert path is not None and path.goal == (0, 6) and path.length_m == pytest.approx(6.0)


def test_shortcut_is_clear_and_not_longer() -> None:
    rng = np.random.default_rng(3)
    blocked = rng.random((40, 40)) < 0.12
    blocked[0, 0] = blocked[39, 39] = False
    path = astar(blocked, (0, 0), (39, 39), resolution_m=1.0)
    assert path is not None
    corners = shortcut(path.cells, blocked)
    assert corners[0] == path.cells[0] and corners[-1] == path.cells[-1]
    assert len(corners) < len(path.cells)
    for a, b in zip(corners, corners[1:], strict=False):
        assert line_of_sight(blocked, a, b)
    as_points = [(float(c), float(r)) for r, c in corners]
    assert path_length(as_points) <= path.length_m + 1e-9


def test_line_of_sight_refuses_a_diagonal_squeeze() -> None:
    blocked = np.zeros((3, 3), dtype=bool)
    blocked[0, 1] = blocked[1, 0] = True
    assert not line_of_sight(blocked, (0, 0), (1, 1))
    assert line_of_sight(blocked, (1, 1), (2, 2))


def test_densify_spacing() -> None:
    points = densify([(0.0, 0.0), (5.0, 0.0), (5.0, 1.0)], 2.0)
    assert points[0] == (0.0, 0.0) and points[-1] == (5.0, 1.0)
    assert all(math.dist(p, q) <= 2.0 + 1e-9 for p, q in zip(points, points[1:], strict=False))
    assert path_length(points) == pytest.approx(6.0)
