"""LiDAR, camera and detector against a room with known geometry."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from llmnav.core.geometry import Pose2D
from llmnav.sim.world import World
from llmnav.world.scenario import LidarConfig


def _ray(scan, angle_deg: float) -> float:
    i = int(np.argmin(np.abs(scan.angles - math.radians(angle_deg))))
    return float(scan.ranges[i])


def test_lidar_range_to_known_walls(world: World) -> None:
    world.reset(Pose2D(0.5, 0.0, 0.0))
    scan = world.lidar.scan()
    assert len(scan.angles) == 360 and np.all(np.diff(scan.angles) > 0)
    assert abs(_ray(scan, 0.0) - 2.4) < 0.02  # east face at x = 2.9
    assert abs(_ray(scan, 90.0) - 3.9) < 0.02  # CCW positive: +90 deg looks north (face y = 3.9)
    assert abs(_ray(scan, -90.0) - 3.9) < 0.02
    assert abs(_ray(scan, 180.0 - 1e-9) - 4.4) < 0.02 or abs(_ray(scan, -180.0) - 4.4) < 0.02
    # Rotating the robot rotates the scan: facing north, the east wall is at -90 deg.
    world.reset(Pose2D(0.5, 0.0, math.pi / 2))
    assert abs(_ray(world.lidar.scan(), -90.0) - 2.4) < 0.02


def test_lidar_out_of_range_is_inf_and_never_sees_robot(make_room) -> None:
    with World(make_room(), lidar=LidarConfig(range_m=2.0)) as w:
        w.reset(Pose2D(0.0, 0.0, 0.0))
        scan = w.lidar.scan()
        assert np.isinf(_ray(scan, 0.0))  # wall at 2.9 m > 2 m range
        finite = scan.ranges[np.isfinite(scan.ranges)]
        assert np.all(finite > w.robot.spec.radius_m)  # nothing from the robot's own body


def test_lidar_noise_is_seeded(make_room) -> None:
    cfg = LidarConfig(noise_std_m=0.01)
    with World(make_room(), lidar=cfg, seed=3) as a, World(make_room(), lidar=cfg, seed=3) as b:
        sa, sb = a.lidar.scan(), b.lidar.scan()
        assert np.array_equal(sa.ranges, sb.ranges)
        a.reset(Pose2D(0, 0, 0), seed=4)
        assert not np.array_equal(a.lidar.scan().ranges, sb.ranges)


def test_non_solid_object_is_seen_but_not_hit(world: World) -> None:
    world.reset(Pose2D(0.0, 0.0, 0.0))
    ghost_bearing = math.degrees(math.atan2(-1.0, 2.5))  # -21.8 deg
    # The ray through the ghost's centre goes on to the east wall behind it (its near face: 2.48 m).
    assert abs(_ray(world.lidar.scan(), ghost_bearing) - 2.9 / math.cos(math.radians(ghost_bearing))) < 0.05
    ids = {d.object_id for d in world.detector.detect()}
    assert "ghost" in ids
    # And the robot drives through it without a collision.
    world.reset(Pose2D(1.4, -1.0, 0.0))
    result = world.motion.drive(1.0)
    assert result.ok and not result.collided


def test_detection_bearing_sign_and_offset(world: World) -> None:
    world.reset(Pose2D(0.0, 0.0, 0.0))
    dets = {d.object_id: d for d in world.detector.detect()}
    ball, ghost = dets["ball"], dets["ghost"]  # ball left (y > 0), ghost right (y < 0)
    assert ball.bearing_deg > 0 and ball.offset < 0
    assert ghost.bearing_deg < 0 and ghost.offset > 0
    assert abs(ball.bearing_deg - math.degrees(math.atan2(0.9, 2.0))) < 1.0
    assert abs(ball.distance_m - math.hypot(2.0, 0.9)) < 1e-6
    assert ball.label == "red ball" and ball.sign == "left" and ghost.sign is None
    assert 0 < ball.pixel_fraction < 1 and -1 <= ball.offset <= 1
    # Turned away, nothing is seen.
    world.reset(Pose2D(0.0, 0.0, math.pi))
    assert world.detector.detect() == []


def test_detector_max_distance_and_dropout(make_room) -> None:
    from llmnav.world.scenario import DetectorConfig

    with World(make_room(), detector=DetectorConfig(max_distance_m=2.4)) as w:
        assert {d.object_id for d in w.detector.detect()} == {"ball"}  # ghost is 2.69 m away
    with World(make_room(), detector=DetectorConfig(dropout=1.0)) as w:
        assert w.detector.detect() == []


def test_camera_frame(world: World) -> None:
    frame = world.camera.capture()
    assert frame.rgb.shape == (480, 640, 3) and frame.rgb.dtype == np.uint8
    assert frame.segmentation is None
    jpeg = frame.image().jpeg_bytes
    decoded = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
    assert decoded.shape == (480, 640, 3)
    small = world.camera.capture(segmentation=True, width=160, height=120)
    assert small.segmentation is not None and small.segmentation.shape == (120, 160)
    ball_body = world.object_bodies["ball"]
    ball_cols = np.nonzero(small.segmentation == ball_body)[1]
    assert ball_cols.size > 0 and ball_cols.mean() < 80  # left half of the image
    # The red ball really is red where the mask says it is.
    full = world.camera.capture(segmentation=True)
    assert full.segmentation is not None
    red = full.rgb[full.segmentation == ball_body].mean(axis=0)
    assert red[0] > red[1] + 50 and red[0] > red[2] + 50


def test_added_obstacle_is_hit_and_named(world: World) -> None:
    world.reset(Pose2D(0.0, 0.0, 0.0))
    body = world.add_obstacle(1.5, 0.0, size=0.4)
    assert abs(_ray(world.lidar.scan(), 0.0) - 1.3) < 0.02
    assert world.object_at_body(body) is None
    assert world.object_at_body(world.object_bodies["ball"]) == "ball"


def test_lidar_fov_config(make_room) -> None:
    with World(make_room(), lidar=LidarConfig(fov_deg=90.0, rays=9)) as w:
        w.reset(Pose2D(0.5, 0.0, 0.0))
        scan = w.lidar.scan()
        assert np.allclose(np.degrees(scan.angles), np.linspace(-45.0, 45.0, 9))
        assert abs(scan.ranges[4] - 2.4) < 0.02
        assert abs(scan.ranges[8] - 2.4 / math.cos(math.radians(45))) < 0.03  # the east wall at +45 deg


def test_camera_rejects_oversized_frames(world: World) -> None:
    with pytest.raises(ValueError):
        world.camera.capture(width=1280, height=720)


def test_partial_scan(world: World) -> None:
    world.reset(Pose2D(0.5, 0.0, 0.0))
    near = world.lidar.scan(half_angle=math.radians(45), max_range=2.0)
    assert len(near.angles) == 91 and near.range_max == 2.0
    assert np.all(np.abs(near.angles) <= math.radians(45) + 1e-9) and np.isinf(_ray(near, 0.0))
    far = world.lidar.scan(half_angle=math.radians(45))
    assert abs(_ray(far, 0.0) - 2.4) < 0.02


def test_a_ray_reads_the_same_in_a_narrower_scan(world: World) -> None:
    # go_to's obstacle stop casts only its own window: each ray must not depend on the others cast.
    for pose in (Pose2D(0.5, 0.0, 0.0), Pose2D(2.2, 0.6, 0.3), Pose2D(-3.5, 3.4, 2.4)):
        world.reset(pose)
        wide = world.lidar.scan(half_angle=math.radians(90), max_range=0.85)
        narrow = world.lidar.scan(half_angle=math.radians(15), max_range=0.85)
        keep = np.abs(wide.angles) <= math.radians(15)
        assert np.array_equal(wide.angles[keep], narrow.angles)
        assert np.array_equal(wide.ranges[keep], narrow.ranges)


def test_camera_renders_again_only_when_the_view_changed(world: World, monkeypatch: pytest.MonkeyPatch) -> None:
    renders: list[int] = []
    render = world.camera._render
    monkeypatch.setattr(world.camera, "_render", lambda *a, **k: renders.append(1) or render(*a, **k))
    first = world.camera.capture(segmentation=True, width=160, height=120)
    first.rgb[:] = 0  # the caller's copy: drawing on it changes nothing kept
    again = world.camera.capture(segmentation=True, width=160, height=120)
    assert len(renders) == 1
    fresh = render(160, 120, *_view(world, 160, 120), True)
    assert np.array_equal(again.rgb, fresh.rgb) and np.array_equal(again.segmentation, fresh.segmentation)
    world.camera.capture()  # another resolution is another frame
    assert len(renders) == 2
    world.motion.rotate(0.3)
    world.camera.capture(segmentation=True, width=160, height=120)
    assert len(renders) == 3
    world.add_obstacle(1.0, 0.0)  # the robot stands still, but the scene changed
    world.camera.capture(segmentation=True, width=160, height=120)
    assert len(renders) == 4


def _view(world: World, width: int, height: int) -> tuple[object, object]:
    """The view and projection matrices the camera renders with at the robot's pose."""
    import pybullet as p

    from llmnav.sim.sensors import CAMERA_NEAR

    pose, eye, cfg = world.robot.pose(), world.camera.eye(), world.camera.config
    target = (eye[0] + math.cos(pose.yaw), eye[1] + math.sin(pose.yaw), eye[2])
    view = p.computeViewMatrix(eye, target, (0.0, 0.0, 1.0), physicsClientId=world.client)
    aspect = width / height
    proj = p.computeProjectionMatrixFOV(cfg.fov_deg, aspect, CAMERA_NEAR, cfg.far_m, physicsClientId=world.client)
    return view, proj
