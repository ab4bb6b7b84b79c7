"""A PyBullet world built from a `Scenario`: static scenery, the robot, its sensors and motion.

Each `World` owns its own DIRECT physics client (several may coexist in one process) and steps at
240 Hz. Gravity is off: every body but the robot is static, and the robot's base is driven by
velocity, so nothing needs it. The world is deterministic: the same scenario, seed and commands give
the same poses.
"""

from __future__ import annotations

import math
import time
from types import TracebackType

import pybullet as p

from llmnav.core.geometry import Pose2D
from llmnav.core.robot_specs import ROBOT_SPECS
from llmnav.sim.bodies import create_shape
from llmnav.sim.motion import Motion
from llmnav.sim.robot import Robot
from llmnav.sim.sensors import Camera, Detector, Lidar
from llmnav.world.scenario import (
    CameraConfig,
    DetectorConfig,
    LabelledObject,
    LidarConfig,
    Obstacle,
    OdometryConfig,
    Scenario,
)

PHYSICS_HZ = 240  # [Hz]
ADDED_OBSTACLE_HEIGHT = 1.0  # [m]
ADDED_OBSTACLE_COLOR = (0.8, 0.45, 0.1, 1.0)


class World:
    """The simulated world of one episode.

    Fields: `scenario`; `robot` (Robot); `lidar` (Lidar); `low_lidar` (Lidar, just above the floor);
    `camera` (Camera); `detector` (Detector);
    `motion` (Motion); `sim_time` [s] since reset; `step_count`; `dt` [s] physics step; `seed`;
    `client` (the PyBullet physicsClientId); `body_names` (body id -> wall/obstacle
    name or object id); `object_bodies` (object id -> body id); `labelled` (body id -> LabelledObject).
    Sensor configs not given come from the scenario's `sensors` section (odometry errors included;
    `OdometryConfig.exact()` makes odometry equal the true motion).
    """

    def __init__(
        self,
        scenario: Scenario,
        *,
        seed: int = 0,
        lidar: LidarConfig | None = None,
        camera: CameraConfig | None = None,
        detector: DetectorConfig | None = None,
        odometry: OdometryConfig | None = None,
    ) -> None:
        self.scenario = scenario
        self.seed = seed
        self.dt = 1.0 / PHYSICS_HZ  # [s]
        self.step_count = 0  # physics steps since reset (sim_time derives from it, so it never drifts)
        self.realtime = False  # pace physics to the wall clock (`--realtime`); the FSM paces its own ticks
        self._pace_anchor: tuple[float, float] | None = None  # (wall, sim) time pacing started from
        self.client = int(p.connect(p.DIRECT))
        try:
            self._build(scenario, lidar, camera, detector, odometry)
        except BaseException:
            self.close()
            raise

    def _build(
        self,
        scenario: Scenario,
        lidar: LidarConfig | None,
        camera: CameraConfig | None,
        detector: DetectorConfig | None,
        odometry: OdometryConfig | None,
    ) -> None:
        client = self.client
        p.setTimeStep(self.dt, physicsClientId=client)
        p.setGravity(0.0, 0.0, 0.0, physicsClientId=client)
        # Deterministic solver ordering across worlds and runs.
        p.setPhysicsEngineParameter(deterministicOverlappingPairs=1, physicsClientId=client)

        self.body_names: dict[int, str] = {}  # every scenery body -> a name for contact reports
        self.object_bodies: dict[str, int] = {}  # labelled object id -> body id
        self.labelled: dict[int, LabelledObject] = {}  # body id -> labelled object
        for i, wall in enumerate(scenario.walls):
            self._add_scenery(wall, wall.id or f"wall:{i}")
        for i, obstacle in enumerate(scenario.obstacles):
            self._add_scenery(obstacle, obstacle.id or f"obstacle:{i}")
        for obj in scenario.objects:
            body = self._add_scenery(obj, obj.id)
            self.object_bodies[obj.id] = body
            self.labelled[body] = obj
        self._added = 0
        self._scheduled: list[tuple[float, float, float, float]] = []  # (t [s], x [m], y [m], size [m]), by time

        spec = ROBOT_SPECS[scenario.robot]
        sensors = scenario.sensors
        self.robot = Robot(
            p, client, spec, dt=self.dt, body_names=self.body_names, odometry=odometry or sensors.odometry
        )
        lidar_cfg = lidar or sensors.lidar
        camera_cfg = camera or sensors.camera
        # Mount heights come from the robot spec unless the scenario or caller set them explicitly.
        lidar_h = lidar_cfg.mount_height_m if "mount_height_m" in lidar_cfg.model_fields_set else spec.lidar_height_m
        camera_h = (
            camera_cfg.mount_height_m if "mount_height_m" in camera_cfg.model_fields_set else spec.camera_height_m
        )
        self.lidar = Lidar(p, client, self.robot, lidar_cfg, mount_height_m=lidar_h)
        self.low_lidar = Lidar(p, client, self.robot, sensors.low_lidar)
        self.camera = Camera(
            p, client, self.robot, camera_cfg, mount_height_m=camera_h, floor_color=scenario.floor_color
        )
        self.detector = Detector(self.camera, self.robot, self.labelled, detector or sensors.detector)
        self.motion = Motion(self)
        self.reset(scenario.default_start.pose())

    def _add_scenery(self, shape: Obstacle | LabelledObject, name: str) -> int:
        body = create_shape(p, self.client, shape)
        self.body_names[body] = name
        return body

    @property
    def sim_time(self) -> float:
        """Physics time [s] since the last reset."""
        return self.step_count * self.dt

    def reset(self, start: Pose2D, *, seed: int | None = None) -> None:
        """Put the robot at `start`, zero time, odometry and collision count, restart every noise stream.

        Deterministic: the same start, seed and commands replay the same poses. Obstacles added with
        `add_obstacle` stay (they are part of the episode's world).
        """
        if seed is not None:
            self.seed = seed
        self.step_count = 0
        self._pace_anchor = None
        base = (self.seed % 2**32) * 8  # one independent stream per noise source; any int seed works
        self.robot._reset(start, seed=base + 1)
        self.lidar.reseed(base + 2)
        self.detector.reseed(base + 3)
        self.low_lidar.reseed(base + 4)
        self.motion._reset()

    def step(self, n: int = 1) -> None:
        """Advance the physics `n` steps of 1/240 s, driving the robot with its current command."""
        robot, client = self.robot, self.client
        if self.realtime and self._pace_anchor is None:
            self._pace_anchor = (time.perf_counter(), self.sim_time)
        for _ in range(n):
            robot._before_step()
            p.stepSimulation(physicsClientId=client)
            robot._after_step()
            self.step_count += 1
            if self._scheduled and self.sim_time >= self._scheduled[0][0]:
                self._drop_due()
        if self.realtime:
            self._pace()

    def _pace(self) -> None:
        """Sleep until the wall clock catches up with simulation time.

        Time spent waiting for a model between motions is not made up: when the simulation has fallen
        behind by more than 100 ms, pacing restarts from the present.
        """
        now = time.perf_counter()
        assert self._pace_anchor is not None
        wall0, sim0 = self._pace_anchor
        ahead = (self.sim_time - sim0) - (now - wall0)
        if ahead > 0:
            time.sleep(ahead)
        elif ahead < -0.1:
            self._pace_anchor = (now, self.sim_time)

    def add_obstacle(self, x: float, y: float, size: float = 0.5) -> int:
        """Drop a solid box of `size` [m] (square footprint, 1 m tall) at (x, y); returns its body id."""
        self._added += 1
        shape = Obstacle(
            center=(x, y),
            size=(size, size),
            height=ADDED_OBSTACLE_HEIGHT,
            color=ADDED_OBSTACLE_COLOR,
            id=f"added:{self._added}",
        )
        return self._add_scenery(shape, f"added:{self._added}")

    def schedule_obstacle(self, x: float, y: float, at_s: float, size: float = 0.5) -> None:
        """Drop a box like `add_obstacle` once the simulation clock reaches `at_s` [s] (mid-motion).

        Like a person stepping into the way, it never lands on the robot: while its footprint would overlap
        the robot's, it waits.
        """
        self._scheduled.append((at_s, x, y, size))
        self._scheduled.sort()

    def _drop_due(self) -> None:
        pose, reach = self.robot.pose(), self.robot.spec.radius_m
        for item in [s for s in self._scheduled if s[0] <= self.sim_time]:
            _t, x, y, size = item
            gap = math.hypot(max(abs(pose.x - x) - size / 2, 0.0), max(abs(pose.y - y) - size / 2, 0.0))
            if gap > reach + 0.01:
                self._scheduled.remove(item)
                self.add_obstacle(x, y, size)

    def object_at_body(self, body_id: int) -> str | None:
        """The labelled object id of a body, if it is one."""
        obj = self.labelled.get(body_id)
        return obj.id if obj is not None else None

    def close(self) -> None:
        """Disconnect the physics client (idempotent)."""
        if self.client >= 0:
            p.disconnect(physicsClientId=self.client)
            self.client = -1

    def __enter__(self) -> World:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:  # noqa: BLE001 - interpreter shutdown may have torn pybullet down already
            pass
