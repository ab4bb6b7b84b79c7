"""Odometry drift: the wheel-level error model, its statistics, seeding, and the true pose left alone.

Tolerances: a sample SD over N draws has a relative standard error of 1/sqrt(2(N-1)); each check allows
5 of them (see tests/sim/test_detector_noise.py).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from llmnav.core.geometry import Pose2D, wrap_angle
from llmnav.sim.robot import wheel_odometry
from llmnav.sim.world import World
from llmnav.world.scenario import OdometryConfig


def test_exact_wheels_give_the_true_step() -> None:
    for ds, dyaw in [(0.01, 0.0), (0.0, 0.02), (0.003, -0.01), (-0.002, 0.004)]:
        got = wheel_odometry(
            ds,
            dyaw,
            half_track_m=0.08,
            wheel_scale=(1.0, 1.0),
            track_scale=1.0,
            noise_m_per_sqrt_m=0.0,
            normals=(1.0, -1.0),
        )
        assert got == pytest.approx((ds, dyaw), abs=1e-15)


def test_systematic_errors_scale_distance_and_turns() -> None:
    # Both wheels 1 % large: 1 % more distance, no curve. Track read 2 % wide: turns read 2 % small.
    ds, _ = wheel_odometry(
        1.0,
        0.0,
        half_track_m=0.1,
        wheel_scale=(1.01, 1.01),
        track_scale=1.0,
        noise_m_per_sqrt_m=0.0,
        normals=(0.0, 0.0),
    )
    assert ds == pytest.approx(1.01)
    _, dyaw = wheel_odometry(
        0.0, 1.0, half_track_m=0.1, wheel_scale=(1.0, 1.0), track_scale=1.02, noise_m_per_sqrt_m=0.0, normals=(0.0, 0.0)
    )
    assert dyaw == pytest.approx(1.0 / 1.02)
    # Unequal wheels on a straight line: a steady curve of (e_r - e_l) / (2 b) rad per metre.
    _, curve = wheel_odometry(
        1.0,
        0.0,
        half_track_m=0.1,
        wheel_scale=(1.005, 0.995),
        track_scale=1.0,
        noise_m_per_sqrt_m=0.0,
        normals=(0.0, 0.0),
    )
    assert curve == pytest.approx(0.01 / 0.2)


def test_random_walk_grows_with_the_square_root_of_distance() -> None:
    # Straight 1 mm steps: each wheel's error has variance k^2 * travel; the mean of two independent
    # wheels has variance k^2 * L / 2 after L metres, so SD k * sqrt(L / 2) whatever the step size.
    k, steps, step, runs = 0.01, 400, 0.001, 4000
    rng = np.random.default_rng(0)
    normals = rng.standard_normal((runs, steps, 2))
    totals = np.zeros(runs)
    for r in range(runs):
        totals[r] = sum(
            wheel_odometry(
                step,
                0.0,
                half_track_m=0.08,
                wheel_scale=(1.0, 1.0),
                track_scale=1.0,
                noise_m_per_sqrt_m=k,
                normals=(n[0], n[1]),
            )[0]
            for n in normals[r]
        )
    errors = totals - steps * step
    expected = k * math.sqrt(steps * step / 2.0)  # 0.0045 m over 0.4 m
    assert abs(errors.std(ddof=1) / expected - 1.0) < 5.0 / math.sqrt(2.0 * (runs - 1))


def _quarter_turn(world: World, seed: int) -> tuple[float, float]:
    """Spin a quarter turn open loop; (true yaw change, odometry yaw change) [rad]."""
    world.reset(Pose2D(0.0, 0.0, 0.0), seed=seed)
    for _ in range(40):
        world.motion.velocity_tick(0.0, math.pi / 2 / 0.8, 0.02)  # 0.8 s at the rate of a quarter turn
    world.robot.halt()
    return world.robot.pose().yaw, world.robot.odom().yaw


def test_track_width_error_per_episode_has_the_configured_spread(make_room) -> None:
    cfg = OdometryConfig(wheel_scale_std=0.0, track_scale_std=0.02, wheel_noise_m_per_sqrt_m=0.0)
    ratios = []
    with World(make_room(robot="burger"), odometry=cfg) as world:
        for seed in range(120):
            true, measured = _quarter_turn(world, seed)
            ratios.append(true / measured - 1.0)  # = the episode's track scale error
    spread = float(np.std(ratios, ddof=1))
    assert abs(spread / 0.02 - 1.0) < 5.0 / math.sqrt(2.0 * (len(ratios) - 1))


def test_drift_is_seeded_and_never_touches_the_true_pose(make_room) -> None:
    cfg = OdometryConfig(wheel_scale_std=0.01, track_scale_std=0.02, wheel_noise_m_per_sqrt_m=0.02)

    def drive(world: World, seed: int) -> tuple[Pose2D, Pose2D]:
        world.reset(Pose2D(0.0, 0.0, 0.0), seed=seed)
        for i in range(150):  # open loop: the commands do not depend on odometry
            world.motion.velocity_tick(0.3, 0.6 * math.sin(i / 15), 0.02)
        return world.robot.pose(), world.robot.odom()

    with World(make_room(), odometry=cfg) as noisy, World(make_room(), odometry=OdometryConfig.exact()) as exact:
        true_a, odom_a = drive(noisy, 3)
        assert drive(noisy, 3) == (true_a, odom_a)  # same seed, same drift
        true_b, odom_b = drive(noisy, 4)
        assert odom_b != odom_a
        assert true_a == true_b  # the truth does not depend on the odometry's errors
        true_x, odom_x = drive(exact, 3)
        assert true_x == true_a
        # Exact wheels: only the integration's sub-millimetre error (sideways slip, arc steps) remains ...
        assert odom_x.distance_to(true_x.x, true_x.y) < 1e-3 and abs(wrap_angle(odom_x.yaw - true_x.yaw)) < 1e-6
        # ... while drifting wheels are off by centimetres after 0.9 m (random walk SD 0.02 * sqrt(0.45)).
        assert odom_a.distance_to(true_a.x, true_a.y) > 5e-3


def test_worlds_without_a_published_map_have_drift_on() -> None:
    from llmnav.world.scenario import load_scenario

    for name in ("factory", "maze_arena"):  # sensed worlds: the pose comes from odometry alone
        assert load_scenario(name).sensors.odometry == OdometryConfig.typical(), name
    for name in ("corridor_a", "corridor_b", "corridor_c"):  # a published map to localise against
        assert load_scenario(name).sensors.odometry.is_exact, name
