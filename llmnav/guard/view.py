"""What a planner may touch of the simulated world: read-only sensors and the guarded motion layer.

`PlannerWorld` is the `world` of a planner's `EpisodeContext`. It mirrors the public reading surface of
`llmnav.sim.world.World` (`robot.pose()`, `robot.odom()`, `robot.spec`, `lidar.scan()`, `low_lidar.scan()`,
`camera.capture()`,
`camera.config`, `detector.detect()`, `sim_time`) so planner code reads the same, but it holds no public
handle to the physics, the raw robot or the raw `Motion`: every motion goes through `GuardedMotion`, and
the world's `Motion` gets the collision monitor (`llmnav.nav.monitor`), which judges every command on
every physics step from then on.
(Python cannot hide an object from a determined caller; the handles here are name-mangled private
attributes, and `tests/guard/test_no_raw_access.py` walks every registered planner's context and source.)
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from llmnav.guard.motion import GuardedMotion, MotionGuardConfig
from llmnav.nav.monitor import CollisionMonitor

if TYPE_CHECKING:
    from llmnav.core.geometry import Pose2D
    from llmnav.core.robot_specs import RobotSpec
    from llmnav.sim.sensors import CameraFrame, Detection, Lidar, LidarScan
    from llmnav.sim.world import World
    from llmnav.world.scenario import CameraConfig, LidarConfig


# Noise streams of the monitor's casts (the world's own sources use 1-4 of each seed's 8).
MONITOR_STREAMS = (5, 6)


class RobotView:
    """The robot's pose, odometry and numbers; nothing that moves it."""

    def __init__(self, world: World) -> None:
        self.__robot = world.robot
        self.spec: RobotSpec = world.robot.spec

    def pose(self) -> Pose2D:
        """Ground-truth pose (for logging and map-aware planners; stepwise models never see it)."""
        return self.__robot.pose()

    def odom(self) -> Pose2D:
        """Odometry pose."""
        return self.__robot.odom()

    def contact_points(self) -> list[tuple[int, float, float, float]]:
        """The bump sensor: (body id, normal x, normal y, distance [m]) of each touch (see `Robot`)."""
        return self.__robot.contact_points()


class LidarView:
    """A planar scanner; remembers the latest full scan so the motion layer checks what the planner just saw."""

    def __init__(self, world: World, lidar: Lidar | None = None) -> None:
        """The LiDAR, or another scanner of the world's (`world.low_lidar`)."""
        self.__world = world
        self.__lidar = lidar if lidar is not None else world.lidar
        self.config: LidarConfig = self.__lidar.config
        self.__last: tuple[LidarScan, Pose2D, int] | None = None  # (scan, pose, physics step) of the latest

    def scan(self, *, half_angle: float | None = None, max_range: float | None = None) -> LidarScan:
        """One scan (see `Lidar.scan`); full scans are remembered for the motion layer."""
        world = self.__world
        scan = self.__lidar.scan(half_angle=half_angle, max_range=max_range)
        if half_angle is None and max_range is None:
            self.__last = (scan, world.robot.pose(), world.step_count)
        return scan

    def latest(self, max_age_s: float) -> tuple[LidarScan, Pose2D]:
        """A full scan taken no more than `max_age_s` [s] of sim time ago (at this very step for 0)."""
        world = self.__world
        last = self.__last
        if last is None or (world.step_count - last[2]) * world.dt > max_age_s + 1e-12:
            self.scan()
            last = self.__last
        assert last is not None
        return last[0], last[1]


class _MonitorSource:
    """A scanner as the collision monitor casts it, with a noise stream of its own.

    The monitor's casts draw their range noise from their own generator (restarted from the world's seed
    with each episode), so the scans planners take read exactly what they would without the monitor.
    """

    def __init__(self, name: str, lidar: Lidar, world: World, stream: int) -> None:
        self.name = name
        self.__lidar = lidar
        self.__world = world
        self.__stream = stream
        self.__rng = np.random.default_rng(0)
        self.reset()

    def reset(self) -> None:
        """Restart the noise stream from the world's seed."""
        self.__rng = np.random.default_rng((self.__world.seed % 2**32) * 8 + self.__stream)

    def cast(self, max_range_m: float) -> LidarScan:
        """A fresh full scan cut at `max_range_m` [m]."""
        return self.__lidar.scan(max_range=max_range_m, rng=self.__rng)


class CameraView:
    """The front camera."""

    def __init__(self, world: World) -> None:
        self.__camera = world.camera
        self.config: CameraConfig = world.camera.config

    def capture(self, *args: Any, **kwargs: Any) -> CameraFrame:
        """One frame (see `Camera.capture`)."""
        return self.__camera.capture(*args, **kwargs)


class DetectorView:
    """The object detector."""

    def __init__(self, world: World) -> None:
        self.__detector = world.detector

    def detect(self, frame: CameraFrame | None = None) -> list[Detection]:
        """Objects in view (see `Detector.detect`)."""
        return self.__detector.detect(frame)


class _TimedLog:
    """Stamps each of the layer's events with the current simulated time."""

    def __init__(self, log: Any, world: World) -> None:
        self.__log = log
        self.__world = world

    def event(self, kind: str, **fields: Any) -> None:
        self.__log.sim_time = self.__world.sim_time
        self.__log.event(kind, **fields)


class PlannerWorld:
    """A planner's view of the world: `robot`, `lidar`, `camera`, `detector`, `motion`, `sim_time`."""

    def __init__(self, world: World, log: Any, config: MotionGuardConfig | None = None) -> None:
        """`log` is the run log (anything with `event(kind, **fields)` and a `sim_time` attribute)."""
        self.__world = world
        self.robot = RobotView(world)
        self.lidar = LidarView(world)
        self.low_lidar = LidarView(world, world.low_lidar)
        self.camera = CameraView(world)
        self.detector = DetectorView(world)
        robot = world.robot
        # The collision monitor judges every command of every motion from here on; nothing a planner holds
        # can take it out again.
        monitor = CollisionMonitor(
            robot.spec,
            [
                _MonitorSource("LiDAR", world.lidar, world, MONITOR_STREAMS[0]),
                _MonitorSource("low scanner", world.low_lidar, world, MONITOR_STREAMS[1]),
            ],
            robot.odom,
            lambda: world.sim_time,
            dt=world.dt,
            max_linear_acc=robot.max_linear_acc,
            max_angular_acc=robot.max_angular_acc,
        )
        world.motion.monitor = monitor
        self.motion = GuardedMotion(
            world.motion,
            self.robot,
            self.lidar,
            _TimedLog(log, world),
            robot_max_linear_acc=robot.max_linear_acc,
            config=config,
            low_scans=self.low_lidar,
            monitor=monitor,
        )

    @property
    def sim_time(self) -> float:
        """Simulated time [s] since the episode started."""
        return self.__world.sim_time
