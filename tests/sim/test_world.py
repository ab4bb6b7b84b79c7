"""World construction from a scenario: bodies, names, shapes, reset and close."""

from __future__ import annotations

import math

import numpy as np

from llmnav.core.geometry import Pose2D
from llmnav.core.robot_specs import BURGER, PR2
from llmnav.sim.world import World


def test_bodies_and_names(world: World) -> None:
    assert set(world.object_bodies) == {"ball", "ghost"}
    for object_id, body in world.object_bodies.items():
        assert world.object_at_body(body) == object_id
    assert world.object_at_body(-1) is None
    assert sorted(n for n in world.body_names.values() if n not in world.object_bodies) == [
        "east",
        "north",
        "south",
        "west",
    ]
    assert world.robot.spec is PR2 and world.lidar.mount_height_m == PR2.lidar_height_m
    assert world.camera.mount_height_m == PR2.camera_height_m


def test_starts_at_default_start_and_resets(make_room) -> None:
    with World(make_room(default_start={"x": 1.0, "y": -0.5, "yaw_deg": 90})) as w:
        start = w.robot.pose()
        assert (start.x, start.y) == (1.0, -0.5) and abs(start.yaw - math.pi / 2) < 1e-9
        w.motion.drive(0.5)
        assert w.sim_time > 0
        w.reset(Pose2D(0.0, 0.0, 0.0))
        assert w.sim_time == 0.0 and w.robot.pose() == Pose2D(0.0, 0.0, 0.0) == w.robot.odom()
        assert w.motion.collisions == 0


def test_yawed_box_and_lifted_plate(make_room) -> None:
    obstacles = [{"center": [2.0, 0.0], "size": [1.0, 0.2], "yaw_deg": 90, "height": 1.0}]
    # A plate high on a wall: above the LiDAR plane, yet visible to the camera.
    objects = [
        {
            "id": "plate",
            "label": "room 101",
            "center": [2.0, 2.0],
            "size": [0.1, 0.6],
            "height": 0.4,
            "z": 1.0,
            "color": [0, 0.6, 0, 1],
        }
    ]
    with World(make_room(obstacles=obstacles, objects=objects, robot="burger")) as w:
        assert w.robot.spec is BURGER
        w.reset(Pose2D(0.0, 0.0, 0.0))
        scan = w.lidar.scan()
        # Turned by 90 deg the 1.0 x 0.2 box is 0.2 deep along x: near face at 1.9.
        assert abs(scan.ranges[180] - 1.9) < 0.02
        w.reset(Pose2D(0.0, 2.0, 0.0))
        scan = w.lidar.scan()
        assert abs(scan.ranges[180] - 2.9) < 0.02  # straight under the plate to the east wall
        w.reset(Pose2D(-2.0, 2.0, 0.0))
        frame = w.camera.capture(segmentation=True, width=160, height=120)
        assert frame.segmentation is not None
        rows = np.nonzero(frame.segmentation == w.object_bodies["plate"])[0]
        assert rows.size > 0 and rows.mean() < 60  # seen above the horizon (camera at 0.19 m)


def test_close_is_idempotent(make_room) -> None:
    w = World(make_room())
    w.close()
    w.close()
    assert w.client == -1
