"""The detector's error model: distance noise growing with range, bias, bearing noise, dropout, maximum
range, occlusion and determinism per seed, checked against the configured numbers.

Statistics use one segmentation frame read many times (the frame is fixed, only the noise is drawn), so
thousands of readings cost little. Tolerances are sampling tolerances, not fudge: with N independent
Gaussian readings the sample SD has a relative standard error of 1/sqrt(2(N-1)) (1.6 % at N = 2000) and
the sample mean a standard error of sigma/sqrt(N); a binomial rate has sqrt(p(1-p)/N). Each check allows
5 standard errors (a false failure about once in 1.7 million for a correct model), while a wrong model
(sigma ignoring range, the bias not applied, another dropout) misses by far more.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from llmnav.core.geometry import Pose2D
from llmnav.sim.sensors import DETECTOR_SIZE, Detection
from llmnav.sim.world import World
from llmnav.world.scenario import DetectorConfig

N = 2000  # readings per statistic
BALL = (2.0, 0.9)  # [m] the ball's centre in the test room (tests/sim/conftest.py)
SD_TOL = 5.0 / math.sqrt(2.0 * (N - 1))  # relative tolerance on a sample SD


def readings(world: World, pose: Pose2D, n: int = N) -> list[Detection]:
    """`n` readings of the ball from one pose (one frame, noise drawn afresh each time)."""
    world.reset(pose)
    frame = world.camera.capture(segmentation=True, width=DETECTOR_SIZE[0], height=DETECTOR_SIZE[1])
    out = []
    for _ in range(n):
        ball = [d for d in world.detector.detect(frame) if d.object_id == "ball"]
        out.extend(ball)
    return out


@pytest.mark.parametrize("pose", [Pose2D(0.0, 0.0, 0.0), Pose2D(1.2, 0.0, 0.3)], ids=["far", "near"])
def test_distance_error_sd_grows_with_range_as_configured(make_room, pose: Pose2D) -> None:
    a, b = 0.02, 0.05  # [m], [m/m]
    cfg = DetectorConfig(distance_noise_std_m=a, distance_noise_per_m=b)
    true = math.hypot(BALL[0] - pose.x, BALL[1] - pose.y)
    expected_sd = a + b * true  # 0.130 m at 2.19 m, 0.080 m at 1.20 m
    with World(make_room(), detector=cfg, seed=11) as world:
        errors = np.array([d.distance_m - true for d in readings(world, pose)])
    assert errors.size == N
    assert abs(errors.std(ddof=1) / expected_sd - 1.0) < SD_TOL
    assert abs(errors.mean()) < 5.0 * expected_sd / math.sqrt(N)


def test_distance_bias_is_relative(make_room) -> None:
    cfg = DetectorConfig(distance_noise_std_m=0.05, distance_bias=0.1)
    true = math.hypot(*BALL)
    with World(make_room(), detector=cfg, seed=2) as world:
        errors = np.array([d.distance_m - true for d in readings(world, Pose2D(0.0, 0.0, 0.0))])
    assert abs(errors.mean() - 0.1 * true) < 5.0 * 0.05 / math.sqrt(N)  # reads 10 % long: +0.219 m


def test_bearing_noise_sd_and_offset_move_together(make_room) -> None:
    pose = Pose2D(0.0, 0.0, 0.0)
    true_bearing = math.degrees(math.atan2(BALL[1], BALL[0]))
    with World(make_room(), seed=5) as ideal:
        exact = readings(ideal, pose, 1)[0]
    assert abs(exact.bearing_deg - true_bearing) < 1e-9
    with World(make_room(), detector=DetectorConfig(bearing_noise_std_deg=2.0), seed=5) as world:
        dets = readings(world, pose)
    errors = np.array([d.bearing_deg - true_bearing for d in dets])
    assert abs(errors.std(ddof=1) / 2.0 - 1.0) < SD_TOL
    assert abs(errors.mean()) < 5.0 * 2.0 / math.sqrt(N)
    # A bearing read further left puts the centroid further left (negative offset): the two agree.
    shifts = np.array([d.offset - exact.offset for d in dets])
    assert np.corrcoef(errors, shifts)[0, 1] < -0.99
    assert all(d.distance_m == exact.distance_m for d in dets)  # distance untouched by bearing noise


def test_dropout_rate(make_room) -> None:
    p = 0.3
    with World(make_room(), detector=DetectorConfig(dropout=p), seed=9) as world:
        seen = len(readings(world, Pose2D(0.0, 0.0, 0.0)))
    assert abs((N - seen) / N - p) < 5.0 * math.sqrt(p * (1 - p) / N)


def test_maximum_range_gates_on_the_true_distance(make_room) -> None:
    # The ball is 2.193 m away; a limit just above it keeps it in every frame even when readings scatter
    # far beyond the limit, and one just below drops it every time.
    noisy = {"distance_noise_std_m": 0.5}
    with World(make_room(), detector=DetectorConfig(max_distance_m=2.2, **noisy), seed=1) as world:
        dets = readings(world, Pose2D(0.0, 0.0, 0.0), 200)
        assert len(dets) == 200 and max(d.distance_m for d in dets) > 2.2
    with World(make_room(), detector=DetectorConfig(max_distance_m=2.18, **noisy), seed=1) as world:
        assert readings(world, Pose2D(0.0, 0.0, 0.0), 50) == []


def test_same_seed_same_readings_other_seed_other_readings(make_room) -> None:
    cfg = DetectorConfig(distance_noise_per_m=0.1, bearing_noise_std_deg=3.0, dropout=0.2)
    pose = Pose2D(0.0, 0.0, 0.0)
    with World(make_room(), detector=cfg, seed=4) as a, World(make_room(), detector=cfg, seed=4) as b:
        first = [a.detector.detect() for _ in range(10)]
        assert first == [b.detector.detect() for _ in range(10)]
        a.reset(pose, seed=4)  # a reset restarts the stream
        assert [a.detector.detect() for _ in range(10)] == first
        a.reset(pose, seed=5)
        assert [a.detector.detect() for _ in range(10)] != first


def test_occlusion_center_needs_a_clear_ray_to_the_centre(make_room) -> None:
    # A 2 m pillar 10 cm wide on the line from the camera (0.38, 0, 1.2) to the ball's centre (2.0, 0.9,
    # 0.75), 0.65 m from the camera: it hides +-4 deg of the ball's +-6.5 deg, so both edges stay in view.
    pillar = {"id": "pillar", "center": [1.03, 0.36], "size": [0.1, 0.1], "height": 2.0}
    scenario = make_room(obstacles=[pillar])
    pose = Pose2D(0.0, 0.0, 0.0)
    with World(scenario, detector=DetectorConfig(occlusion="mask")) as world:
        world.reset(pose)
        assert "ball" in {d.object_id for d in world.detector.detect()}
    with World(scenario, detector=DetectorConfig(occlusion="center")) as world:
        world.reset(pose)
        seen = {d.object_id for d in world.detector.detect()}
        assert "ball" not in seen and "ghost" in seen  # the ghost's centre is in plain view
        world.reset(Pose2D(0.0, 0.6, 0.0))  # step aside: the centre reappears
        assert "ball" in {d.object_id for d in world.detector.detect()}
