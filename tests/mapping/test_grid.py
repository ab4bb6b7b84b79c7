"""Occupancy grids: exact rasterisation and inflation of yawed boxes and cylinders; LiDAR ray casting."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest

from llmnav.core.geometry import Pose2D
from llmnav.core.robot_specs import BURGER, PR2
from llmnav.mapping.grid import GridConfig, GridGeometry, LidarMap, build_grid, inflate
from llmnav.world.scenario import parse_scenario


def small_scenario(robot: str = "burger") -> object:
    return parse_scenario(
        {
            "name": "grid-test",
            "robot": robot,
            "bounds": {"x": [0.0, 6.0], "y": [0.0, 4.0]},
            "obstacles": [
                {"center": [2.0, 2.0], "size": [1.2, 0.4], "yaw_deg": 30.0},
                {"shape": "cylinder", "center": [4.5, 1.2], "radius": 0.3},
                {"center": [4.5, 3.2], "size": [0.6, 0.6], "z": 2.0},  # hung above the robot: not an obstacle
            ],
            "objects": [
                {"id": "plate", "label": "plate", "center": [1.0, 3.5], "size": [0.3, 0.02], "solid": False}
            ],
            "default_start": {"x": 0.5, "y": 0.5},
        },
        "grid-test",
    )


def test_geometry_round_trip() -> None:
    sc = small_scenario()
    geometry = GridGeometry.from_bounds(sc.bounds, 0.05)
    assert geometry.shape == (80, 120)
    for x, y in [(0.01, 0.01), (2.337, 1.5), (5.99, 3.99)]:
        cell = geometry.world_to_cell(x, y)
        cx, cy = geometry.cell_to_world(*cell)
        assert abs(cx - x) <= 0.025 + 1e-12 and abs(cy - y) <= 0.025 + 1e-12
    assert geometry.world_to_cell(0.0, 0.0) == (0, 0)
    assert not geometry.contains(geometry.world_to_cell(-0.01, 1.0))


@pytest.mark.parametrize("robot", ["burger", "pr2"])
def test_inflation_matches_exact_shape_distance(robot: str) -> None:
    sc = small_scenario(robot)
    spec = {"burger": BURGER, "pr2": PR2}[robot]
    config = GridConfig(resolution_m=0.05, margin_m=0.1)
    grid = build_grid(sc, config=config)
    inflation = spec.radius_m + 0.1
    assert grid.inflation_m == pytest.approx(inflation)
    solids = [s for s in sc.solid_shapes() if s.z < spec.height_m]
    assert len(solids) == 2  # the hung box and the non-solid plate are left out
    xs, ys = grid.geometry.centres()
    for row in range(0, grid.geometry.rows, 3):
        for col in range(0, grid.geometry.cols, 3):
            x, y = float(xs[row, col]), float(ys[row, col])
            near_shape = min(s.distance_to(x, y) for s in solids) <= inflation
            near_bounds = min(x, 6.0 - x, y, 4.0 - y) < inflation
            assert grid.blocked[row, col] == (near_shape or near_bounds), (x, y)
            if any(s.contains(x, y) for s in solids):
                assert grid.occupied[row, col]
    # The yawed box's corner region: a point just beyond the rotated corner but inside the axis-aligned
    # bounding box must not be occupied.
    assert not grid.occupied[grid.geometry.world_to_cell(2.55, 1.55)]
    assert grid.occupied[grid.geometry.world_to_cell(2.0, 2.0)]
    assert grid.is_free(3.2, 3.0) and not grid.is_free(4.5, 1.2)


def test_inflate_distance_transform() -> None:
    mask = np.zeros((21, 21), dtype=bool)
    mask[10, 10] = True
    grown = inflate(mask, 0.25, 0.05)  # 5 cells
    rows, cols = np.nonzero(grown)
    assert np.hypot(rows - 10, cols - 10).max() == pytest.approx(5.0)
    assert grown.sum() == sum(1 for r in range(21) for c in range(21) if math.hypot(r - 10, c - 10) <= 5)


@dataclass
class FakeScan:
    angles: np.ndarray
    ranges: np.ndarray
    range_max: float


def square_room_scan(pose: Pose2D, half: float, rays: int, range_max: float) -> FakeScan:
    """Analytic ranges from `pose` to the walls of the square [-half, half]^2."""
    angles = np.linspace(-math.pi, math.pi, rays, endpoint=False)
    world = angles + pose.yaw
    with np.errstate(divide="ignore"):
        tx = np.where(np.cos(world) > 0, (half - pose.x) / np.cos(world), (-half - pose.x) / np.cos(world))
        ty = np.where(np.sin(world) > 0, (half - pose.y) / np.sin(world), (-half - pose.y) / np.sin(world))
    ranges = np.minimum(np.abs(tx), np.abs(ty))
    return FakeScan(angles, np.where(ranges <= range_max, ranges, np.inf), range_max)


def test_lidar_map_ray_casting() -> None:
    sc = parse_scenario(
        {"name": "room", "bounds": {"x": [-3.0, 3.0], "y": [-3.0, 3.0]}, "robot": "burger"}, "room"
    )
    geometry = GridGeometry.from_bounds(sc.bounds, 0.05)
    lidar_map = LidarMap(geometry)
    assert lidar_map.unknown.all()
    pose = Pose2D(-0.5, 0.3, 0.7)
    lidar_map.integrate(pose, square_room_scan(pose, 2.0, 720, 10.0))
    # The walls of the 4 m room are occupied, the inside free, the outside unknown.
    assert (
        lidar_map.occupied[geometry.world_to_cell(1.99, 0.0)]
        or lidar_map.occupied[geometry.world_to_cell(2.01, 0.0)]
    )
    for x, y in [(0.0, 0.0), (1.5, 1.5), (-1.8, -1.8), (1.0, -1.5)]:
        assert lidar_map.free[geometry.world_to_cell(x, y)], (x, y)
    for x, y in [(2.5, 0.0), (0.0, -2.6), (-2.8, 2.8)]:
        assert lidar_map.unknown[geometry.world_to_cell(x, y)], (x, y)
    # No free cell lies beyond the walls.
    xs, ys = geometry.centres()
    outside = (np.abs(xs) > 2.05) | (np.abs(ys) > 2.05)
    assert not (lidar_map.free & outside).any()
    # A second scan never frees an occupied cell.
    occupied_before = lidar_map.occupied.copy()
    pose2 = Pose2D(0.8, -0.4, -1.0)
    lidar_map.integrate(pose2, square_room_scan(pose2, 2.0, 720, 10.0))
    assert (lidar_map.occupied | ~occupied_before).all()


def test_lidar_map_max_range_rays_clear_space() -> None:
    geometry = GridGeometry(0.0, 0.0, 0.05, 100, 100)
    lidar_map = LidarMap(geometry)
    # A narrow fan (+-5 deg) of rays that hit nothing within 2 m.
    angles = np.radians(np.linspace(-5.0, 5.0, 11))
    lidar_map.integrate(Pose2D(1.0, 2.5, 0.0), FakeScan(angles, np.full(11, np.inf), 2.0))
    assert lidar_map.free[geometry.world_to_cell(2.9, 2.5)]
    assert lidar_map.unknown[geometry.world_to_cell(3.1, 2.5)]
    assert lidar_map.unknown[geometry.world_to_cell(2.5, 3.0)]  # outside the fan
    assert lidar_map.unknown[geometry.world_to_cell(0.5, 2.5)]  # behind the sensor
    assert not lidar_map.occupied.any()


def test_a_scan_from_a_pose_just_off_the_map_frees_what_it_saw_on_the_map() -> None:
    # Drifting odometry can put the believed pose outside the bounds: the scan is still mapped, no crash.
    geometry = GridGeometry(0.0, 0.0, 0.05, 100, 100)
    lidar_map = LidarMap(geometry)
    angles = np.radians(np.linspace(-5.0, 5.0, 11))
    lidar_map.integrate(Pose2D(-0.2, 2.5, 0.0), FakeScan(angles, np.full(11, np.inf), 2.0))
    lidar_map.integrate(Pose2D(5.2, 2.5, math.pi), FakeScan(angles, np.full(11, np.inf), 2.0))
    assert lidar_map.free[geometry.world_to_cell(1.0, 2.5)] and lidar_map.free[geometry.world_to_cell(4.0, 2.5)]
    assert lidar_map.unknown[geometry.world_to_cell(2.5, 2.5)]  # beyond both fans


def test_lidar_map_does_not_free_space_behind_an_edge() -> None:
    geometry = GridGeometry(0.0, 0.0, 0.05, 100, 100)
    lidar_map = LidarMap(geometry)
    angles = np.linspace(-math.pi, math.pi, 360, endpoint=False)
    ranges = np.full(360, np.inf)
    ranges[(angles > 0.0) & (angles < 0.3)] = 1.0  # a short obstacle edge to the left of straight ahead
    lidar_map.integrate(Pose2D(2.5, 2.5, 0.0), FakeScan(angles, ranges, 2.0))
    # Behind the obstacle (bearing 0.15 rad, 1.5 m) stays unknown; the far side of the edge is free.
    assert lidar_map.unknown[geometry.world_to_cell(2.5 + 1.5 * math.cos(0.15), 2.5 + 1.5 * math.sin(0.15))]
    assert lidar_map.free[geometry.world_to_cell(2.5 + 1.5 * math.cos(-0.1), 2.5 + 1.5 * math.sin(-0.1))]
    assert lidar_map.occupied[geometry.world_to_cell(2.5 + math.cos(0.15), 2.5 + math.sin(0.15))]


def test_not_free_within_is_inflate_of_the_map_as_it_stands() -> None:
    sc = parse_scenario({"name": "room", "bounds": {"x": [-3.0, 3.0], "y": [-3.0, 3.0]}, "robot": "burger"}, "room")
    geometry = GridGeometry.from_bounds(sc.bounds, 0.05)
    lidar_map = LidarMap(geometry)
    assert lidar_map.not_free_within(0.3).all()  # all unknown
    for pose in (Pose2D(-0.5, 0.3, 0.7), Pose2D(0.8, -0.4, -1.0)):
        lidar_map.integrate(pose, square_room_scan(pose, 2.0, 720, 10.0))
        for radius in (0.3, 0.45, 0.3):  # the second 0.3 reads the kept transform
            expected = inflate(lidar_map.occupied | lidar_map.unknown, radius, geometry.resolution)
            assert np.array_equal(lidar_map.not_free_within(radius), expected)
    lidar_map.mark_occupied(0.0, 0.0, 0.2)  # a change the cache must see
    expected = inflate(lidar_map.occupied | lidar_map.unknown, 0.3, geometry.resolution)
    assert np.array_equal(lidar_map.not_free_within(0.3), expected)
    lidar_map.state[:] = LidarMap.FREE  # even written directly
    assert not lidar_map.not_free_within(0.3).any()
