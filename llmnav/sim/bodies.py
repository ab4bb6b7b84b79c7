"""Static scenery for a PyBullet world: floor, walls, obstacles and labelled objects as boxes/cylinders.

Every call names its `physicsClientId`, so several worlds can live in one process. A shape with
`solid=False` gets a visual shape only: no collision shape means the robot drives through it and LiDAR
rays miss it, while the renderer still draws it and the segmentation mask still carries its body id.
"""

from __future__ import annotations

import math
from typing import Any

from llmnav.scenario import Bounds, Shape

# Collision groups: the robot's mask leaves out the floor, so the broadphase never even pairs them
# (a floating, gravity-free base has no floor contacts that could pile up and slow the steps).
# Ray casts carry Bullet's default group (1): scenery accepts it, the robot does not, so the LiDAR
# never sees the robot's own body.
RAY_GROUP = 1
SCENERY_GROUP = 2
ROBOT_GROUP = 4
FLOOR_GROUP = 8
FLOOR_THICKNESS = 0.1  # [m]


def _yaw_quaternion(yaw: float) -> tuple[float, float, float, float]:
    return (0.0, 0.0, math.sin(yaw / 2.0), math.cos(yaw / 2.0))


def create_floor(p: Any, client: int, bounds: Bounds, color: tuple[float, float, float, float]) -> int:
    """A thin box whose top face is z = 0, a metre larger than the bounds on every side."""
    half = (
        (bounds.x[1] - bounds.x[0]) / 2.0 + 1.0,
        (bounds.y[1] - bounds.y[0]) / 2.0 + 1.0,
        FLOOR_THICKNESS / 2.0,
    )
    centre = ((bounds.x[0] + bounds.x[1]) / 2.0, (bounds.y[0] + bounds.y[1]) / 2.0, -FLOOR_THICKNESS / 2.0)
    col = p.createCollisionShape(p.GEOM_BOX, halfExtents=half, physicsClientId=client)
    vis = p.createVisualShape(p.GEOM_BOX, halfExtents=half, rgbaColor=color, physicsClientId=client)
    body = int(
        p.createMultiBody(
            baseMass=0.0,
            baseCollisionShapeIndex=col,
            baseVisualShapeIndex=vis,
            basePosition=centre,
            physicsClientId=client,
        )
    )
    p.setCollisionFilterGroupMask(body, -1, FLOOR_GROUP, 0, physicsClientId=client)
    return body


def create_shape(p: Any, client: int, shape: Shape) -> int:
    """A static body for a scenario shape (box or cylinder, lifted by `z`, turned by `yaw`)."""
    centre = (shape.center[0], shape.center[1], shape.z + shape.height / 2.0)
    if shape.shape == "box":
        assert shape.size is not None
        half = (shape.size[0] / 2.0, shape.size[1] / 2.0, shape.height / 2.0)
        vis = p.createVisualShape(p.GEOM_BOX, halfExtents=half, rgbaColor=shape.color, physicsClientId=client)
        col = (
            p.createCollisionShape(p.GEOM_BOX, halfExtents=half, physicsClientId=client)
            if shape.solid
            else -1
        )
    else:
        assert shape.radius is not None
        vis = p.createVisualShape(
            p.GEOM_CYLINDER,
            radius=shape.radius,
            length=shape.height,
            rgbaColor=shape.color,
            physicsClientId=client,
        )
        col = (
            p.createCollisionShape(
                p.GEOM_CYLINDER, radius=shape.radius, height=shape.height, physicsClientId=client
            )
            if shape.solid
            else -1
        )
    body = int(
        p.createMultiBody(
            baseMass=0.0,
            baseCollisionShapeIndex=col,
            baseVisualShapeIndex=vis,
            basePosition=centre,
            baseOrientation=_yaw_quaternion(shape.yaw),
            physicsClientId=client,
        )
    )
    if shape.solid:
        p.setCollisionFilterGroupMask(
            body, -1, SCENERY_GROUP, ROBOT_GROUP | RAY_GROUP, physicsClientId=client
        )
    return body
