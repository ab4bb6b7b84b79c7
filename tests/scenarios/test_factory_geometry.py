"""Factory start poses hide every acceptable target: a 2D ray-casting check independent of the simulator.

Rays fan out over the camera's horizontal field of view (widened to +-45 deg for margin; the real one is
+-37.6 deg) from the robot centre; only objects taller than the camera (walls, cabinets, stacks) block the
view. A target counts as visible if any ray reaches its footprint before a blocker.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from llmnav.world.scenario import Scenario, Shape, Task, load_scenario

HALF_FOV_DEG = 45.0  # [deg] wider than the camera's 37.6 deg, for margin
RAYS = 361
OCCLUDER_HEIGHT = 1.8  # [m] shorter objects, and objects lower than the target, count as see-through
POINT_RADIUS = 0.3  # [m] a point target is seen if a ray passes this close
# A point target between landmarks also counts as seen when its landmarks are.
LANDMARKS = {"T4": ("S", "OB1", "OB2", "OB3")}


def ray_distances(shape: Shape, ox: float, oy: float, dx: np.ndarray, dy: np.ndarray) -> np.ndarray:
    """Distance [m] along each unit ray (dx, dy) from (ox, oy) to the shape's footprint; inf where missed."""
    cx, cy = shape.center
    if shape.shape == "cylinder":
        assert shape.radius is not None
        fx, fy = ox - cx, oy - cy
        b = fx * dx + fy * dy
        c = fx * fx + fy * fy - shape.radius**2
        disc = b * b - c
        t = np.where(c <= 0, 0.0, -b - np.sqrt(np.maximum(disc, 0.0)))
        return np.where((disc >= 0) & (t >= 0), t, np.inf)
    assert shape.size is not None
    # Slab test in the box's own frame.
    ca, sa = math.cos(-shape.yaw), math.sin(-shape.yaw)
    lx, ly = ca * (ox - cx) - sa * (oy - cy), sa * (ox - cx) + ca * (oy - cy)
    ldx, ldy = ca * dx - sa * dy, sa * dx + ca * dy
    t_near = np.full(dx.shape, -np.inf)
    t_far = np.full(dx.shape, np.inf)
    for origin, direction, half in ((lx, ldx, shape.size[0] / 2), (ly, ldy, shape.size[1] / 2)):
        parallel = np.abs(direction) < 1e-12
        safe = np.where(parallel, 1.0, direction)
        t1, t2 = (-half - origin) / safe, (half - origin) / safe
        lo = np.where(parallel, np.where(abs(origin) <= half, -np.inf, np.inf), np.minimum(t1, t2))
        hi = np.where(parallel, np.where(abs(origin) <= half, np.inf, -np.inf), np.maximum(t1, t2))
        t_near, t_far = np.maximum(t_near, lo), np.minimum(t_far, hi)
    hit = (t_far >= t_near) & (t_far >= 0)
    return np.where(hit, np.maximum(t_near, 0.0), np.inf)


def seen_targets(scenario: Scenario, x: float, y: float, yaw: float, targets: dict[str, Shape]) -> list[str]:
    """Names of the target shapes a camera at (x, y) looking along yaw would see."""
    angles = yaw + np.radians(np.linspace(-HALF_FOV_DEG, HALF_FOV_DEG, RAYS))
    dx, dy = np.cos(angles), np.sin(angles)
    seen = []
    for name, target in targets.items():
        blocked = np.full(RAYS, np.inf)
        for shape in scenario.solid_shapes():
            if shape.height >= max(OCCLUDER_HEIGHT, target.height) and shape != target:
                blocked = np.minimum(blocked, ray_distances(shape, x, y, dx, dy))
        if np.any(ray_distances(target, x, y, dx, dy) < blocked):
            seen.append(name)
    return seen


def target_shapes(scenario: Scenario, task: Task) -> dict[str, Shape]:
    """The task's acceptable targets (and landmarks) as footprints."""
    shapes: dict[str, Shape] = {}
    for target in task.targets:
        if target.object is not None:
            shapes[target.object] = scenario.object(target.object)
        else:
            assert target.point is not None
            shapes[f"point{target.point}"] = Shape(shape="cylinder", center=target.point, radius=POINT_RADIUS)
    for object_id in LANDMARKS.get(task.id, ()):
        shapes[object_id] = scenario.object(object_id)
    return shapes


def test_ray_caster_sees_what_is_in_front_and_not_behind_walls() -> None:
    scenario = load_scenario("factory")
    cabinet = {"CC": scenario.object("CC")}  # 2 m wide, its near corners 77 and 103 deg from (1.5, -1)
    assert seen_targets(scenario, 1.5, -1.0, math.radians(90), cabinet) == ["CC"]  # straight ahead
    assert seen_targets(scenario, 1.5, -1.0, math.radians(-90), cabinet) == []  # behind the camera
    assert seen_targets(scenario, 1.5, -1.0, math.radians(160), cabinet) == []  # just outside the view
    assert seen_targets(scenario, 1.5, -1.0, math.radians(135), cabinet) == ["CC"]  # at the edge of the field
    # The 3 m pallet stack hides the 0.9 m one directly behind it (seen from the east along the row).
    stack = {"PS1": scenario.object("PS1")}
    assert seen_targets(scenario, -3.0, -11.75, math.pi, stack) == []
    assert seen_targets(scenario, -6.84, -8.0, -math.pi / 2, stack) == ["PS1"]


@pytest.mark.parametrize("task_id", [f"T{i}" for i in (1, 2, 3, 4, 5, 8, 9, 10)])
def test_no_acceptable_target_in_view_from_any_start_pose(task_id: str) -> None:
    scenario = load_scenario("factory")
    task = scenario.task(task_id)
    targets = target_shapes(scenario, task)
    for i, start in enumerate(task.start_poses):
        seen = seen_targets(scenario, start.x, start.y, math.radians(start.yaw_deg), targets)
        assert seen == [], f"{task_id} start {i + 1} ({start.x}, {start.y}, {start.yaw_deg} deg) sees {seen}"
