"""Perception text: sectors, front distance and the text models read, on synthetic scans."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest

from llmnav.core.geometry import Pose2D
from llmnav.sensing.perception import (
    describe_detections,
    detections_text,
    front_distance,
    lidar_sectors,
    lidar_text,
    pose_text,
    summarize_scan,
)
from llmnav.sim.sensors import LidarScan as Scan


@dataclass
class Det:
    object_id: str
    label: str
    bearing_deg: float
    distance_m: float
    pixel_fraction: float = 0.01
    offset: float = 0.0
    sign: str | None = None


def empty_scan(rays: int = 360, fov_deg: float = 360.0) -> Scan:
    if fov_deg >= 360:
        angles = np.linspace(-math.pi, math.pi, rays, endpoint=False)
    else:
        half = math.radians(fov_deg) / 2
        angles = np.linspace(-half, half, rays)
    return Scan(angles, np.full(rays, np.inf))


def put(scan: Scan, angle_deg: float, distance: float) -> None:
    i = int(np.argmin(np.abs(scan.angles - math.radians(angle_deg))))
    scan.ranges[i] = distance


def test_eight_sectors_over_ninety_degrees_left_to_right() -> None:
    sectors = lidar_sectors(empty_scan(), 8, 90.0)
    assert len(sectors) == 8
    assert sectors[0].start_deg == pytest.approx(45.0) and sectors[-1].end_deg == pytest.approx(-45.0)
    for s in sectors:
        assert s.start_deg - s.end_deg == pytest.approx(11.25)
        assert math.isinf(s.min_m) and s.min_angle_deg is None and s.rays > 0


@pytest.mark.parametrize(("angle", "expected_sector"), [(40.0, 0), (20.0, 2), (5.0, 3), (-5.0, 4), (-44.0, 7)])
def test_sector_min_and_angle(angle: float, expected_sector: int) -> None:
    scan = empty_scan()
    put(scan, angle, 2.5)
    sectors = lidar_sectors(scan, 8, 90.0)
    hit = [i for i, s in enumerate(sectors) if math.isfinite(s.min_m)]
    assert hit == [expected_sector]
    assert sectors[expected_sector].min_m == pytest.approx(2.5)
    assert sectors[expected_sector].min_angle_deg == pytest.approx(angle, abs=0.5)


def test_sector_keeps_the_closest_of_several() -> None:
    scan = empty_scan()
    put(scan, 15.0, 4.0)
    put(scan, 18.0, 1.2)
    put(scan, 21.0, 3.0)
    s = lidar_sectors(scan, 8, 90.0)[2]  # +22.5 .. +11.25
    assert s.min_m == pytest.approx(1.2) and s.min_angle_deg == pytest.approx(18.0, abs=0.5)


def test_rays_outside_the_field_are_ignored() -> None:
    scan = empty_scan()
    put(scan, 90.0, 0.5)
    put(scan, 180.0 - 1, 0.5)
    assert all(math.isinf(s.min_m) for s in lidar_sectors(scan, 8, 90.0))
    assert any(math.isfinite(s.min_m) for s in lidar_sectors(scan, 4, 360.0))


@pytest.mark.parametrize("n", [3, 5, 8])
def test_sector_counts_of_the_ablation(n: int) -> None:
    sectors = lidar_sectors(empty_scan(720), n, 90.0)
    assert len(sectors) == n
    in_field = sum(1 for a in empty_scan(720).angles if abs(a) <= math.pi / 4 + 1e-9)
    assert sum(s.rays for s in sectors) == in_field


def test_sparse_scan_reports_no_data() -> None:
    scan = Scan(np.array([0.0]), np.array([2.0]))
    sectors = lidar_sectors(scan, 8, 90.0)
    assert sum(1 for s in sectors if s.rays == 0) == 7
    assert "no data" in lidar_text(scan, 8, 90.0)


def test_front_distance_is_mean_of_central_readings() -> None:
    scan = empty_scan()
    for angle in (-3.0, -2.0, -1.0, 0.0, 1.0, 2.0, 3.0):
        put(scan, angle, 2.0 + angle / 10)
    assert front_distance(scan) == pytest.approx(2.0)
    put(scan, 3.0, math.inf)  # one ray sees nothing: left out of the mean
    assert front_distance(scan) == pytest.approx((1.7 + 1.8 + 1.9 + 2.0 + 2.1 + 2.2) / 6)


def test_front_distance_inf_and_none() -> None:
    assert front_distance(empty_scan()) == math.inf
    rear_only = Scan(np.linspace(math.pi / 2, math.pi, 30), np.full(30, 1.0))
    assert front_distance(rear_only) is None


def test_nan_readings_are_dropped() -> None:
    scan = empty_scan()
    scan.ranges[:] = np.nan
    sectors = lidar_sectors(scan, 8, 90.0)
    assert all(s.rays == 0 for s in sectors)
    assert front_distance(scan) is None


def test_text_is_compact_and_uses_degrees_and_inf() -> None:
    scan = empty_scan()
    put(scan, 20.0, 2.0)
    put(scan, -40.0, 1.0)
    text = lidar_text(scan, 8, 90.0)
    lines = text.splitlines()
    assert lines[0] == "Front distance: inf m"
    assert len(lines) == 10
    assert "closest 2.00 m at +20.0 deg" in lines[4]
    assert "closest 1.00 m at -40.0 deg" in lines[9]
    assert "closest inf" in lines[2] and "nothing within 10 m" in lines[1]
    summary = summarize_scan(scan, sectors=8, fov_deg=90.0)
    assert summary.text() == text and summary.front_m == math.inf


def test_invalid_arguments() -> None:
    with pytest.raises(ValueError):
        lidar_sectors(empty_scan(), 0)
    with pytest.raises(ValueError):
        lidar_sectors(empty_scan(), 8, 0.0)
    with pytest.raises(ValueError):
        lidar_sectors(Scan(np.zeros(3), np.zeros(4)))


def test_detections_text_nearest_first() -> None:
    dets = [Det("box_2", "red box", -30.0, 4.0), Det("stop_1", "stop sign", 10.0, 1.5, sign="stop")]
    text = detections_text(dets)
    lines = text.splitlines()
    assert "stop sign [id stop_1]: 1.5 m, bearing +10 deg (left), sign: stop" in lines[1]
    assert "red box [id box_2]: 4.0 m, bearing -30 deg (right)" in lines[2]
    assert detections_text([]) == "Detected objects: none in view."
    assert describe_detections(dets) == text


def test_pose_text() -> None:
    assert pose_text(Pose2D(1.0, -2.5, math.pi / 2)) == ("x 1.00 m, y -2.50 m, heading 90 deg (0 = +x, CCW positive)")
