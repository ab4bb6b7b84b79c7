"""Opt-in sensor recording during a drive: what an MCAP export needs beyond the planner's own events.

A run logs the planner's observations (LiDAR summarised into sectors), not the full scans, odometry or
wheel commands between decisions. `Recorder` adds, at a stated rate, `sample` events with the full LiDAR
scan (`ranges_f32`: base64 of little-endian float32 ranges [m], +inf where nothing was hit), the odometry
pose, the commanded and applied velocity; and one `map` event with the world's true
occupancy at the start. The scans come from a second LiDAR of the same model with its own noise stream, so
the planner's sensor readings, and so the run, stay exactly what they are without recording.

Samples are taken when the simulator reports a trajectory pose (every 0.25 s of sim time or 0.1 m of
travel, whichever comes first), so the effective rate is at most that pose rate (4 Hz while still).
"""

from __future__ import annotations

import base64
import copy
import math
from typing import TYPE_CHECKING

import numpy as np

from llmnav.mapping.grid import GridConfig, build_grid

if TYPE_CHECKING:
    from llmnav.runs.runlog import RunLog
    from llmnav.sim.world import World
    from llmnav.world.scenario import Scenario

MAP_RESOLUTION_M = 0.05  # [m] the recorded map's cell side (nav2 maps are commonly 0.05 m)
MAX_RECORD_HZ = 50.0  # [Hz] beyond any pose rate: a larger value is a typo


def check_rate(rate_hz: float) -> float:
    """The recording rate [Hz], or ValueError with the accepted range."""
    if not (math.isfinite(rate_hz) and 0.0 < rate_hz <= MAX_RECORD_HZ):
        raise ValueError(f"recording rate must be in (0, {MAX_RECORD_HZ:g}] Hz, got {rate_hz:g}")
    return rate_hz


def pack_occupancy(occupied: np.ndarray) -> str:
    """Row-major boolean cells (row 0 = southmost) as base64 of their bits (numpy.packbits, big-endian bits)."""
    return base64.b64encode(np.packbits(occupied.astype(bool).ravel()).tobytes()).decode("ascii")


def unpack_occupancy(packed: str, rows: int, cols: int) -> np.ndarray:
    """The inverse of `pack_occupancy`; ValueError unless it holds exactly the bytes rows x cols cells need."""
    data = np.frombuffer(base64.b64decode(packed, validate=True), dtype=np.uint8)
    if len(data) != (rows * cols + 7) // 8:  # unpackbits would pad a short one with free cells
        raise ValueError(f"{len(data)} bytes for {rows} x {cols} cells")
    bits = np.unpackbits(data, count=rows * cols)
    return bits.astype(bool).reshape(rows, cols)


class Recorder:
    """Logs `sample` events at `rate_hz` [Hz] from a trajectory-pose callback, and the `map` event once."""

    def __init__(self, world: World, log: RunLog, rate_hz: float, seed: int) -> None:
        self._world = world
        self._log = log
        self._period_s = 1.0 / check_rate(rate_hz)  # [s]
        self._next_t = -math.inf  # [s] sim time of the next sample
        # A second LiDAR of the same model: rays are read-only queries, its noise stream is its own.
        self._lidar = copy.copy(world.lidar)
        self._lidar.reseed(seed + 7919)
        self.rate_hz = rate_hz

    def log_map(self, scenario: Scenario) -> None:
        """The world's true occupancy (solid shapes the robot cannot pass under), not inflated."""
        grid = build_grid(scenario, config=GridConfig(resolution_m=MAP_RESOLUTION_M))
        g = grid.geometry
        self._log.event(
            "map",
            source="scenario",
            resolution_m=g.resolution,
            origin=[g.origin_x, g.origin_y],
            rows=g.rows,
            cols=g.cols,
            occupied=pack_occupancy(grid.occupied),
        )

    def sample(self, t_sim: float) -> None:
        """Log one sample if the rate says one is due at sim time `t_sim` [s]."""
        if t_sim < self._next_t:
            return
        self._next_t = t_sim + self._period_s
        robot = self._world.robot
        scan = self._lidar.scan()
        angles = scan.angles
        increment = float(angles[1] - angles[0]) if len(angles) > 1 else 0.0  # [rad]
        # float32 as in sensor_msgs/LaserScan, +inf for no return; one base64 string logs ~10x faster than a list
        ranges = base64.b64encode(np.asarray(scan.ranges, dtype="<f4").tobytes()).decode("ascii")
        cmd_v, cmd_w = robot.command()
        v, w = robot.velocity()
        self._log.event(
            "sample",
            pose=robot.pose().as_list(),
            odom=robot.odom().as_list(),
            cmd_vel=[round(cmd_v, 4), round(cmd_w, 4)],
            velocity=[round(v, 4), round(w, 4)],
            scan={
                "angle_min": float(angles[0]),
                "angle_increment": increment,
                "range_min": scan.range_min,
                "range_max": scan.range_max,
                "ranges_f32": ranges,
            },
        )
