"""Random start poses for `reset`: drawn clear of obstacles, reachable, and repeatable by seed.

A start is a cell of the scenario's true occupancy grid (`llmnav.mapping.grid.build_grid`) that is not
*blocked* (its centre keeps the robot radius + the grid's margin from every solid shape and the bounds),
in the same free region as the task's listed start (so the target stays reachable by driving), optionally
within `radius_m` of that listed start; the point is the cell centre jittered within the cell, and the
heading is uniform in [-pi, pi). The draw uses only the generator it is given, so the environment's seeded
`np_random` repeats it for the same seed.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
from scipy import ndimage

from llmnav.core.geometry import Pose2D
from llmnav.errors import BadInputError
from llmnav.mapping.grid import build_grid

if TYPE_CHECKING:
    from llmnav.core.robot_specs import RobotSpec
    from llmnav.mapping.grid import OccupancyGrid
    from llmnav.world.scenario import Scenario


class StartSampler:
    """Free, reachable start cells of one scenario (the grid is built once per environment)."""

    def __init__(self, scenario: Scenario, robot: RobotSpec) -> None:
        self.grid: OccupancyGrid = build_grid(scenario, robot=robot)
        free = ~self.grid.blocked
        # 8-connected free regions: a robot centre can move between diagonal neighbours of free cells.
        self._regions, _ = ndimage.label(free, structure=np.ones((3, 3), dtype=bool))
        self._name = scenario.name

    def candidates(self, anchor: Pose2D, radius_m: float | None) -> np.ndarray:
        """(rows, cols) of the free cells in `anchor`'s region (within `radius_m` [m] of it when given)."""
        geometry = self.grid.geometry
        row, col = geometry.world_to_cell(anchor.x, anchor.y)
        region = int(self._regions[row, col]) if geometry.contains((row, col)) else 0
        if region == 0:  # the listed start is itself in an inflated cell (close to a wall): any free region
            mask = self._regions > 0
        else:
            mask = self._regions == region
        if radius_m is not None:
            xs, ys = geometry.centres()
            mask &= np.hypot(xs - anchor.x, ys - anchor.y) <= radius_m
        cells = np.argwhere(mask)
        if len(cells) == 0:
            within = f" within {radius_m:g} m of" if radius_m is not None else " around"
            raise BadInputError(f"{self._name}: no free cell{within} the start ({anchor.x:.2f}, {anchor.y:.2f})")
        return cells

    def draw(self, rng: np.random.Generator, anchor: Pose2D, radius_m: float | None = None) -> Pose2D:
        """One start pose drawn with `rng` (see the module docstring)."""
        cells = self.candidates(anchor, radius_m)
        row, col = cells[int(rng.integers(len(cells)))]
        geometry = self.grid.geometry
        x, y = geometry.cell_to_world(int(row), int(col))
        half = geometry.resolution / 2.0  # [m] jitter within the cell: starts are not on a lattice
        jitter_x, jitter_y = rng.uniform(-half, half, size=2)
        yaw = float(rng.uniform(-math.pi, math.pi))
        return Pose2D(float(x + jitter_x), float(y + jitter_y), yaw)
