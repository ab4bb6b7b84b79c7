"""Motion primitives: discrete moves, turns, collisions, go_to, velocity ticks, determinism."""

from __future__ import annotations

import math

from llmnav.core.geometry import Pose2D, wrap_angle
from llmnav.sim.world import World
from llmnav.world.scenario import OdometryConfig


def test_front_one_metre(world: World) -> None:
    world.reset(Pose2D(0.0, 0.0, 0.0))
    result = world.motion.drive(1.0)
    end = world.robot.pose()
    assert result.ok and not result.collided and result.stopped_reason is None
    assert abs(end.x - 1.0) < 0.03 and abs(end.y) < 0.03
    assert abs(result.distance_m - 1.0) < 0.03 and result.end == end
    assert 1.0 / world.robot.spec.max_linear < result.duration_s < 6.0


def test_front_along_a_diagonal_heading(world: World) -> None:
    world.reset(Pose2D(-1.0, -1.0, math.radians(30)))
    world.motion.drive(1.5)
    end = world.robot.pose()
    assert math.hypot(end.x - (-1.0 + 1.5 * math.cos(math.radians(30))), end.y - (-1.0 + 0.75)) < 0.03


def test_back(world: World) -> None:
    world.reset(Pose2D(0.0, 0.0, 0.0))
    result = world.motion.drive(-1.0)
    end = world.robot.pose()
    assert result.ok and abs(end.x + 1.0) < 0.03 and abs(end.y) < 0.03
    assert abs(wrap_angle(end.yaw)) < math.radians(1.0)


def test_rotate_left_and_right(world: World) -> None:
    world.reset(Pose2D(0.0, 0.0, 0.0))
    left = world.motion.rotate(math.pi / 2)
    assert left.ok and abs(math.degrees(world.robot.pose().yaw) - 90.0) < 1.5
    assert abs(math.degrees(left.rotated_rad) - 90.0) < 1.5
    right = world.motion.rotate(-math.radians(135))
    assert right.ok and abs(math.degrees(world.robot.pose().yaw) - (-45.0)) < 1.5
    # A full turn comes back to the start heading.
    world.motion.rotate(2 * math.pi)
    assert abs(math.degrees(wrap_angle(world.robot.pose().yaw + math.radians(45)))) < 1.5


def test_collision_stops_and_counts(world: World) -> None:
    world.reset(Pose2D(0.0, 0.0, 0.0))
    radius = world.robot.spec.radius_m
    result = world.motion.drive(5.0)  # the east wall's face is at x = 2.9
    assert result.collided and not result.ok
    assert result.collision_with == "east" and result.stopped_reason == "collision"
    assert world.motion.collisions == 1
    end = world.robot.pose()
    assert 2.9 - radius - 0.03 < end.x <= 2.9 - radius + 0.01  # stopped at the wall, not through it
    assert world.robot.contacts() == ["east"]
    # Driving into it again counts again; backing away does not collide.
    assert world.motion.drive(0.5).collided and world.motion.collisions == 2
    back = world.motion.drive(-1.0)
    assert back.ok and not back.collided and world.motion.collisions == 2
    assert world.robot.contacts() == []


def test_nothing_passes_through_walls_under_velocity_commands(world: World) -> None:
    world.reset(Pose2D(2.0, 0.0, 0.0))
    hits = 0
    for _ in range(200):  # 4 s of pushing at full speed
        hits += world.motion.velocity_tick(1.0, 0.0).collided
    assert hits > 0 and world.robot.pose().x < 2.9 - world.robot.spec.radius_m + 0.01
    assert world.motion.collisions == 1  # one continuous contact is one collision


def test_go_to_reaches_point(world: World) -> None:
    world.reset(Pose2D(0.0, 0.0, 0.0))
    samples: list[tuple[Pose2D, float]] = []
    world.motion.on_pose = lambda pose, t: samples.append((pose, t))
    result = world.motion.go_to(-2.0, 2.5)
    end = world.robot.pose()
    assert result.ok and math.hypot(end.x + 2.0, end.y - 2.5) <= 0.1
    # Trajectory samples: spaced, in time order, ending at the final pose.
    assert len(samples) >= 10 and samples[-1][0] == end
    pairs = list(zip(samples, samples[1:], strict=False))
    assert all(b[1] >= a[1] for a, b in pairs)
    assert all(math.hypot(b[0].x - a[0].x, b[0].y - a[0].y) < 0.15 for a, b in pairs)


def test_go_to_obstacle_stop_before_contact(world: World) -> None:
    world.reset(Pose2D(0.0, 0.0, 0.0))
    world.add_obstacle(2.0, 0.0, size=0.4)  # near face at x = 1.8
    scans: list[float] = []
    result = world.motion.go_to(
        2.5, 0.0, obstacle_stop_m=0.8, emergency_stop_m=0.5, on_sample=lambda pose, scan: scans.append(pose.x)
    )
    assert not result.ok and not result.collided and result.stopped_reason == "obstacle"
    assert 1.8 - 0.8 - 0.1 < world.robot.pose().x < 1.8 - 0.5 and scans


def test_go_to_respects_burger_speed_cap(make_room) -> None:
    with World(make_room(robot="burger")) as w:
        w.reset(Pose2D(0.0, 0.0, 0.0))
        result = w.motion.go_to(2.0, 0.0)
        assert result.ok and result.duration_s >= 1.9 / 0.4


def test_velocity_tick_sim_time_is_exact(world: World) -> None:
    world.reset(Pose2D(0.0, 0.0, 0.0))
    for _ in range(50):
        r = world.motion.velocity_tick(0.2, 0.0)
        assert abs(r.duration_s * 240 - 4) < 1e-9 or abs(r.duration_s * 240 - 5) < 1e-9
    assert world.step_count == 240 and abs(world.sim_time - 1.0) < 1e-12
    for _ in range(450):
        world.motion.velocity_tick(0.0, 0.5)
    assert world.step_count == 2400 and abs(world.sim_time - 10.0) < 1e-12
    # 1 s at 0.2 m/s, less the acceleration ramp.
    world.reset(Pose2D(0.0, 0.0, 0.0))
    for _ in range(50):
        world.motion.velocity_tick(0.2, 0.0)
    assert 0.17 < world.robot.pose().x <= 0.2


def test_idle_robot_has_no_contacts(world: World) -> None:
    world.reset(Pose2D(0.0, 0.0, 0.0))
    world.step(240)
    assert world.robot.contacts() == [] and world.robot.pose() == Pose2D(0.0, 0.0, 0.0)


def _script(w: World) -> list[Pose2D]:
    poses = []
    w.motion.drive(1.2)
    poses.append(w.robot.pose())
    w.motion.rotate(math.radians(70))
    poses.append(w.robot.pose())
    w.motion.go_to(-1.0, 2.0)
    poses.append(w.robot.pose())
    for i in range(100):
        w.motion.velocity_tick(0.3, 0.5 * math.sin(i / 10))
    poses.append(w.robot.pose())
    w.motion.drive(10.0)  # ends in a collision
    poses.append(w.robot.pose())
    poses.append(w.robot.odom())
    return poses


def test_determinism_across_worlds(make_room) -> None:
    drift = OdometryConfig(wheel_scale_std=0.02, track_scale_std=0.02, wheel_noise_m_per_sqrt_m=0.02)
    with World(make_room(), seed=7, odometry=drift) as a, World(make_room(), seed=7, odometry=drift) as b:
        pa, pb = _script(a), _script(b)
        assert pa == pb
        assert a.robot.odom() != a.robot.pose()  # the noise really is on
        # A reset world replays the same episode.
        a.reset(a.scenario.default_start.pose())
        assert _script(a) == pa


def test_worlds_do_not_interfere(make_room) -> None:
    with World(make_room()) as a, World(make_room()) as b:
        a.reset(Pose2D(0.0, 0.0, 0.0))
        b.reset(Pose2D(0.0, 0.0, 0.0))
        a.add_obstacle(1.0, 0.0, size=0.4)
        a.motion.drive(-1.0)
        scan_b = b.lidar.scan()
        assert b.robot.pose() == Pose2D(0.0, 0.0, 0.0) and b.sim_time == 0.0
        assert abs(scan_b.ranges[180] - 2.9) < 0.02  # b does not see a's obstacle
        assert abs(a.lidar.scan().ranges[180] - 1.8) < 0.02
        b.motion.drive(1.0)
        assert abs(a.robot.pose().x + 1.0) < 0.03


def test_back_into_wall_collides(world: World) -> None:
    world.reset(Pose2D(2.0, 0.0, math.pi))  # facing west, the east wall behind
    result = world.motion.drive(-2.0)
    assert result.collided and result.collision_with == "east" and world.motion.collisions == 1
    assert world.robot.pose().x <= 2.9 - world.robot.spec.radius_m + 0.01


def test_timeouts_end_motions(world: World) -> None:
    world.reset(Pose2D(0.0, 0.0, 0.0))
    result = world.motion.go_to(-3.0, 3.0, timeout_s=1.0)
    assert not result.ok and result.stopped_reason == "timeout" and abs(result.duration_s - 1.0) < 0.01
    assert world.robot.velocity() == (0.0, 0.0)  # halted
    assert world.motion.drive(2.0, timeout_s=0.5).stopped_reason == "timeout"
