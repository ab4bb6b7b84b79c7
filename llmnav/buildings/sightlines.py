"""Whether a target can be seen from a start pose: a 2D line-of-sight test, as simple as it can be.

From the start position, a target counts as visible when a straight line reaches any of its sample points
(its goal point, and its footprint's corners pulled 10 %
towards its centre) without crossing a blocker. Blockers are the walls and every solid shape standing on
the floor at least as tall as the robot's camera (a sofa does not hide a fridge from a camera above it; a
wardrobe does); the target itself never blocks. Doorway lintels hang above the floor and do not block.

With a heading, only sample points within `half_fov` of it count (the camera's view at the start pose);
without one, every direction counts (the robot may turn on the spot first): the generator asks the
stricter question, `scenarios check` the camera's.

It is a geometric test of the floor plan, not a render: a thin gap between two blockers counts as a view,
and a target hidden behind low furniture only from below the camera counts as visible.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from llmnav.core.geometry import Point
    from llmnav.world.scenario import LabelledObject, Scenario, Shape

SAMPLE_PULL = 0.1  # [-] corners are pulled this fraction of the way to the centre


def blockers(scenario: Scenario, eye_height_m: float, exclude: set[str]) -> list[Shape]:
    """Walls and solid floor-standing shapes at least `eye_height_m` [m] tall, minus the objects `exclude` names."""
    out: list[Shape] = [w for w in scenario.walls if w.z == 0.0]
    for shape in [*scenario.obstacles, *scenario.objects]:
        if getattr(shape, "id", None) in exclude or not shape.solid or shape.z > 0.0:
            continue
        if shape.height >= eye_height_m:
            out.append(shape)
    return out


def sample_points(obj: LabelledObject) -> list[Point]:
    """The goal point and the footprint's corners, pulled towards the centre."""
    cx, cy = obj.center
    points: list[Point] = [obj.goal_point]
    if obj.shape == "cylinder":
        assert obj.radius is not None
        reach = obj.radius * (1 - SAMPLE_PULL)
        angles = (0.0, math.pi / 2, math.pi, -math.pi / 2)
        return points + [(cx + reach * math.cos(a), cy + reach * math.sin(a)) for a in angles]
    assert obj.size is not None
    hx, hy = obj.size[0] / 2 * (1 - SAMPLE_PULL), obj.size[1] / 2 * (1 - SAMPLE_PULL)
    c, s = math.cos(obj.yaw), math.sin(obj.yaw)
    for lx, ly in ((hx, hy), (-hx, hy), (-hx, -hy), (hx, -hy)):
        points.append((cx + c * lx - s * ly, cy + s * lx + c * ly))
    return points


def crosses(shape: Shape, a: Point, b: Point) -> bool:
    """Whether the segment a-b passes through the shape's footprint."""
    ax, ay = a[0] - shape.center[0], a[1] - shape.center[1]
    bx, by = b[0] - shape.center[0], b[1] - shape.center[1]
    if shape.shape == "cylinder":
        assert shape.radius is not None
        dx, dy = bx - ax, by - ay
        length2 = dx * dx + dy * dy
        t = 0.0 if length2 == 0 else max(0.0, min(1.0, -(ax * dx + ay * dy) / length2))
        return math.hypot(ax + t * dx, ay + t * dy) < shape.radius
    assert shape.size is not None
    c, s = math.cos(-shape.yaw), math.sin(-shape.yaw)
    p0 = (c * ax - s * ay, s * ax + c * ay)
    p1 = (c * bx - s * by, s * bx + c * by)
    # Liang-Barsky clipping of the segment against the box [-hx, hx] x [-hy, hy] (strict: grazing is a miss).
    t0, t1 = 0.0, 1.0
    for start, delta, half in ((p0[0], p1[0] - p0[0], shape.size[0] / 2), (p0[1], p1[1] - p0[1], shape.size[1] / 2)):
        if delta == 0.0:
            if not -half < start < half:
                return False
            continue
        ta, tb = (-half - start) / delta, (half - start) / delta
        t0, t1 = max(t0, min(ta, tb)), min(t1, max(ta, tb))
        if t0 >= t1:
            return False
    return True


def visible(
    start: Point, obj: LabelledObject, blocking: list[Shape], heading: float | None = None, half_fov: float = math.pi
) -> bool:
    """Whether a sample point of `obj` is in line of sight from `start` (within `half_fov` [rad] of `heading`)."""
    for point in sample_points(obj):
        if heading is not None:
            bearing = math.atan2(point[1] - start[1], point[0] - start[0]) - heading
            if abs((bearing + math.pi) % (2 * math.pi) - math.pi) > half_fov:
                continue
        if not any(crosses(shape, start, point) for shape in blocking):
            return True
    return False
