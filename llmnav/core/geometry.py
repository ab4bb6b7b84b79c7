"""Planar poses and angle helpers shared by the simulator, planners and metrics."""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

Point = tuple[float, float]  # [m] a world point (x, y)


def wrap_angle(angle_rad: float) -> float:
    """Wrap an angle to [-pi, pi)."""
    return (angle_rad + math.pi) % (2.0 * math.pi) - math.pi


def path_length(points: Iterable[Sequence[float]]) -> float:
    """Length [m] of a polyline through (x, y, ...) points: trajectory samples, planned paths alike."""
    total = 0.0
    previous: Sequence[float] | None = None
    for point in points:
        if previous is not None:
            total += math.hypot(point[0] - previous[0], point[1] - previous[1])
        previous = point
    return total


MAX_LOGGED_COORD_M = 1e6  # [m] no world is this large: a logged coordinate beyond it is damage, not a pose


def logged_pose(value: object) -> list[float] | None:
    """A pose read from a log, [x, y(, yaw)] as floats; None unless every number is real and finite.

    Logs are files a user may edit: NaN, 1e308 or a string where a number belongs count as no pose
    (views and scores skip it) rather than reaching arithmetic and plotting that cannot take them.
    """
    if not isinstance(value, (list, tuple)) or len(value) < 2:
        return None
    head = value[:3]
    if not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in head):
        return None
    if abs(head[0]) > MAX_LOGGED_COORD_M or abs(head[1]) > MAX_LOGGED_COORD_M:
        return None
    return [float(v) for v in head]


@dataclass(frozen=True)
class Pose2D:
    """A planar pose in the world frame: x, y [m] and yaw [rad], counter-clockwise from +x."""

    x: float
    y: float
    yaw: float

    def distance_to(self, x: float, y: float) -> float:
        """Euclidean distance [m] from this pose's position to a point."""
        return math.hypot(x - self.x, y - self.y)

    def bearing_to(self, x: float, y: float) -> float:
        """Signed angle [rad] from the heading to the direction of a point (positive = to the left)."""
        return wrap_angle(math.atan2(y - self.y, x - self.x) - self.yaw)

    def point_at(self, bearing_rad: float, range_m: float) -> Point:
        """The world point seen `range_m` [m] away at `bearing_rad` [rad] from the heading (+ = left)."""
        heading = self.yaw + bearing_rad
        return (self.x + range_m * math.cos(heading), self.y + range_m * math.sin(heading))

    def carry(self, x: float, y: float, onto: Pose2D) -> tuple[float, float]:
        """The point lying relative to `onto` as (x, y) lies relative to this pose (a change of frame)."""
        dx, dy = x - self.x, y - self.y
        turn = onto.yaw - self.yaw
        c, s = math.cos(turn), math.sin(turn)
        return onto.x + c * dx - s * dy, onto.y + s * dx + c * dy

    def as_list(self) -> list[float]:
        """[x, y, yaw] rounded for logs (mm and mrad precision is plenty for replay comparisons)."""
        return [round(self.x, 4), round(self.y, 4), round(self.yaw, 4)]

    @classmethod
    def from_list(cls, values: list[float] | tuple[float, ...]) -> Pose2D:
        """Inverse of `as_list`."""
        return cls(float(values[0]), float(values[1]), float(values[2]))
