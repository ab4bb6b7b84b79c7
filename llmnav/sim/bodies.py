"""Static scenery for a PyBullet world: walls, obstacles and labelled objects as boxes/cylinders.

There is no floor body: the robot floats on the plane z = 0 without touching it (so no floor contacts
can pile up), rays are horizontal, and the camera paints the floor into the background below the
horizon (a floor-sized box would be the single most expensive thing TinyRenderer draws).

Every call names its `physicsClientId`, so several worlds can live in one process. A shape with
`solid=False` gets a visual shape only: no collision shape means the robot drives through it and LiDAR
rays miss it, while the renderer still draws it and the segmentation mask still carries its body id.
"""

from __future__ import annotations

import math
from typing import Any

from llmnav.world.scenario import Shape

# Collision groups. Ray casts carry Bullet's default group (1): scenery accepts it, the robot does not,
# so the LiDAR never sees the robot's own body.
RAY_GROUP = 1
SCENERY_GROUP = 2
ROBOT_GROUP = 4


def _yaw_quaternion(yaw: float) -> tuple[float, float, float, float]:
    return (0.0, 0.0, math.sin(yaw / 2.0), math.cos(yaw / 2.0))


def create_shape(p: Any, client: int, shape: Shape) -> int:
    """A static body for a scenario shape (box or cylinder, lifted by `z`, turned by `yaw`)."""
    centre = (shape.center[0], shape.center[1], shape.z + shape.height / 2.0)
    if shape.shape == "box":
        assert shape.size is not None
        half = (shape.size[0] / 2.0, shape.size[1] / 2.0, shape.height / 2.0)
        vis = p.createVisualShape(p.GEOM_BOX, halfExtents=half, rgbaColor=shape.color, physicsClientId=client)
        col = p.createCollisionShape(p.GEOM_BOX, halfExtents=half, physicsClientId=client) if shape.solid else -1
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
            p.createCollisionShape(p.GEOM_CYLINDER, radius=shape.radius, height=shape.height, physicsClientId=client)
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
            # Static scenery needs no articulated body: maximal coordinates make each physics step cheaper
            # in worlds of many boxes (an imported map: ~2 ms -> ~0.4 ms a step with 1,200 boxes).
            useMaximalCoordinates=True,
            physicsClientId=client,
        )
    )
    if shape.solid:
        p.setCollisionFilterGroupMask(body, -1, SCENERY_GROUP, ROBOT_GROUP | RAY_GROUP, physicsClientId=client)
    return body
