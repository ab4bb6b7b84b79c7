"""Waypoint plans against the map (source B's rules, docs/sources.md B): every problem, named point by point.

`validate_waypoints` lists each broken rule (inside a corridor with the margin, spacing, count, final point
on the target, segments clear of the inflated map and of obstacles seen on the way); `PlanRules` applies
them as the guard's bounds, so a plan that breaks them is sent back with every problem listed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from llmnav.core.geometry import Point

if TYPE_CHECKING:
    from llmnav.mapping.grid import OccupancyGrid
    from llmnav.world.scenario import Scenario, WaypointRules

# No map is near this size: a longer segment (a point at 1e308) leaves the map within it, so only its
# first part is sampled; sampling all of it would overflow the step count or loop for hours.
MAX_SAMPLED_M = 1_000.0  # [m]
SAMPLE_STEP_M = 0.05  # [m]


def _metres(value: float) -> str:
    """A coordinate or distance for a message: `12.34`, but `1e+308` rather than 309 digits."""
    return f"{value:.2f}" if abs(value) < 1e12 else f"{value:.3g}"


def validate_waypoints(
    points: list[Point],
    start: Point,
    target: Point,
    scenario: Scenario,
    grid: OccupancyGrid | None,
    rules: WaypointRules,
    *,
    extra_obstacles: list[Point] | None = None,
    obstacle_radius_m: float = 0.35,
) -> list[str]:
    """Every problem of a plan, each naming the point and the rule; empty when the plan is valid."""
    problems: list[str] = []
    margin = rules.margin_m
    if len(points) > rules.max_waypoints:
        problems.append(f"{len(points)} waypoints; at most {rules.max_waypoints} are allowed here")
    previous = start
    for index, (x, y) in enumerate(points, start=1):
        name = f"waypoint {index} ({_metres(x)}, {_metres(y)})"
        if not any(c.contains(x, y, margin) for c in scenario.corridors):
            problems.append(f"{name} is outside every corridor with the {margin} m margin")
        gap = math.dist(previous, (x, y))
        if index < len(points) and gap < rules.spacing_m:
            problems.append(f"{name} is {gap:.2f} m from the previous point; keep at least {rules.spacing_m} m")
        blocked = _segment_blocked(previous, (x, y), grid, extra_obstacles or [], obstacle_radius_m)
        if blocked is not None:
            (bx, by), seen = blocked
            seen_text = " seen on the way" if seen else ""
            problems.append(f"the segment to {name} crosses an obstacle near ({bx:.2f}, {by:.2f}){seen_text}")
        previous = (x, y)
    if points:
        miss = math.dist(points[-1], target)
        if miss > rules.target_tolerance_m:
            problems.append(
                f"the final waypoint is {_metres(miss)} m from the target ({target[0]:.2f}, {target[1]:.2f}); "
                f"it must be within {rules.target_tolerance_m} m"
            )
    return problems


def _segment_blocked(
    a: Point, b: Point, grid: OccupancyGrid | None, extra: list[Point], radius: float
) -> tuple[Point, bool] | None:
    """Where segment a-b first meets an obstacle, if it does.

    (the first sample inside the inflated map grid, False), or (the centre of an obstacle seen on the
    way that the segment passes within `radius` [m] of, True).
    """
    for x, y in _samples(a, b):
        # the first 0.15 m are exempt: a robot stopped close to a wall may start inside its inflation
        if grid is not None and not grid.is_free(x, y) and math.dist((x, y), a) > 0.15:
            return (x, y), False
        for obstacle in extra:
            if math.dist((x, y), obstacle) < radius:
                return obstacle, True
    return None


def _samples(a: Point, b: Point) -> list[Point]:
    """Points every `SAMPLE_STEP_M` from a to b, both ends included; at most `MAX_SAMPLED_M` of it."""
    length = math.dist(a, b)
    if length <= MAX_SAMPLED_M:
        steps = max(1, math.ceil(length / SAMPLE_STEP_M))
        return [(a[0] + (b[0] - a[0]) * k / steps, a[1] + (b[1] - a[1]) * k / steps) for k in range(steps + 1)]
    # Halves keep the difference finite even from -1e308 to 1e308.
    half_x, half_y = b[0] / 2 - a[0] / 2, b[1] / 2 - a[1] / 2
    half = math.hypot(half_x, half_y)
    ux, uy = half_x / half, half_y / half
    steps = math.ceil(MAX_SAMPLED_M / SAMPLE_STEP_M)
    return [(a[0] + ux * SAMPLE_STEP_M * k, a[1] + uy * SAMPLE_STEP_M * k) for k in range(steps + 1)]


@dataclass(frozen=True)
class PlanRules:
    """The map rules as guard bounds: a plan read from the answer must satisfy `validate_waypoints`."""

    scenario: Scenario
    start: Point
    target: Point
    grid: OccupancyGrid | None
    seen_obstacles: list[Point]
    clearance_m: float

    def problems(self, points: list[Point]) -> list[str]:
        """Every broken rule, one sentence each."""
        return validate_waypoints(
            points,
            self.start,
            self.target,
            self.scenario,
            self.grid,
            self.scenario.waypoint_rules,
            extra_obstacles=self.seen_obstacles,
            obstacle_radius_m=self.clearance_m,
        )

    def check(self, value: Any) -> str | None:
        """The broken rules, one per line, or None."""
        found = self.problems([(float(x), float(y)) for x, y in value.points])
        return "\n".join(found) or None
