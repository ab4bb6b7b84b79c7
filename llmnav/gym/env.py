"""Gymnasium environments over llmnav's worlds: the three sources' protocols behind `reset`/`step`.

- `FactoryEnv` (`llmnav/Factory-v0`): the stepwise source's discrete actions (FRONT/BACK metres,
  ROTATE_LEFT/ROTATE_RIGHT degrees, COMPLETE) on the factory world.
- `VelocityEnv` (`llmnav/Maze-v0`, `llmnav/Corridor-v0`): a velocity command (v [m/s], w [rad/s]) held for
  one control period: 20 ms in the maze (the FSM source's 50 Hz loop), 100 ms in the corridors.

The environments wrap the existing `World` (physics, sensors), task resolution and the score of
`llmnav.scoring.metrics`; they add no physics or scoring of their own. Safety is not inside: `SafetyVeto`
(`llmnav.gym.wrappers`) is the wrapper `gymnasium.make` adds by default, as Gymnasium does cross-cutting
behaviour.

Observation (a `Dict`; `odom` and `task` always, the rest as `sensing` asks, by default all):
- `image`: `Box(uint8, H×W×3)`, the front camera (RGB), `image_height` × `image_width` (default 120 × 160).
- `lidar`: `Box(float32, (rays,))`, ranges [m] from the robot centre, counter-clockwise from the right edge
  of the field of view; readings beyond range are `range_m` (the scenario's LiDAR range).
- `sectors`: `Box(float32, (lidar_sectors, 2))`, the summary llmnav's planners are told, left to right over
  `lidar_fov_deg`: column 0 the closest reading [m] (`range_m` when the sector sees nothing), column 1 the
  bearing of that reading [rad, left positive] (the sector's centre when it sees nothing).
- `odom`: `Box(float32, (3,))`, the odometry pose (x [m], y [m], yaw [rad]) in the map frame. Never the
  true pose: that is for the reward and the score only.
- `detections`: `Box(float32, (MAX_DETECTIONS, 3))`, one row per detected labelled object: bearing [rad,
  left positive], distance [m], horizontal image offset in [-1, 1]; padded with zeros.
- `detection_class`: `MultiDiscrete`, per row 0 for padding, else 1 + the index of the detected label in
  `env.unwrapped.labels` (sorted labels of the scenario's objects; sign classes in the maze).
- `detection_mask`: `MultiBinary(MAX_DETECTIONS)`, 1 where a row holds a detection.
- `goal` (with `observe_goal=True`, "map" information only): `Box(float32, (3,))`, the task's target as
  the map places it, seen from the odometry pose: distance [m], sine and cosine of its bearing (left
  positive). The map point and the odometry, never the true pose; zeros for a task without a target point.
- `task`: `Text` (`TaskText`), the task as given (characters outside printable ASCII shown as `?`).

Start: the task's listed start pose (`start_pose`, 1-based), or with `start="random"` (a `make` keyword or
`reset(options={"start": "random"})`) a pose drawn from the environment's seeded generator: a free cell
of the true occupancy grid reachable from the listed start, within `start_radius_m` of it when given, and
a uniform heading (`llmnav.gym.starts`). The same seed draws the same start; `info["start"]` gives it.

Reward (`reward="score_delta"`, default): the change of the stepwise source's score S = distance_score ×
heading_score of the true pose against the task's best target (rotate tasks: S = 1 once the net rotation
reaches the full turn), plus `success_bonus` on the step that ends the episode with success (a completed
episode within 2.5 m, as `llmnav score` counts it). `reward="progress"`: the metres by which the step
brought the true pose nearer the best target (negative when it went away; S's change for a task without
target points), plus the same bonus: S stops changing within 2.5 m, where a velocity agent still has to
close in to `arrive_radius_m`. `reward="sparse"`: only the bonus.

`terminated`: the agent said COMPLETE (Factory), or a velocity agent stopped within `arrive_radius_m` of
a target. `truncated`: `max_steps` steps taken.

`info`: `score`, `distance_m` (to the best target, None without one), `success`, `path_length_m` (true
trajectory), `collisions`, `sim_time_s`, `steps`, `information` ("map" or "sensed"); after `reset` also
`start` (the start pose [x m, y m, yaw rad]) and, in "map" mode, `map` (corridor rectangles and labelled
objects with positions, the map such a scenario publishes); `vetoed` (the reason) when the safety layer
refused or overrode the action. `SafetyVeto` adds `vetoes` and `guard_events`.
"""

from __future__ import annotations

import math
import os
import string
from typing import TYPE_CHECKING, Any, ClassVar, Literal

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from llmnav.core.geometry import Pose2D, wrap_angle
from llmnav.core.robot_specs import ROBOT_SPECS
from llmnav.errors import BadInputError, validation_message
from llmnav.gym.starts import StartSampler
from llmnav.gym.text_space import TaskText
from llmnav.reporting.topview import raster_scenario
from llmnav.scoring.metrics import SUCCESS_RADIUS_M, best_target, rotation_done
from llmnav.sensing.perception import lidar_sectors
from llmnav.sim.sensors import DETECTOR_SIZE
from llmnav.sim.world import World
from llmnav.world.scenario import load_scenario
from llmnav.world.tasks import resolve_task

if TYPE_CHECKING:
    from llmnav.sim.motion import MotionResult
    from llmnav.sim.sensors import Detection, LidarScan
    from llmnav.world.scenario import Scenario, Task

MAX_DETECTIONS = 8  # rows of the padded detection table
TASK_CHARSET = frozenset(string.ascii_letters + string.digits + string.punctuation + " ")
MAX_TASK_CHARS = 512
ODOM_LIMIT_M = 1.0e4  # [m] bound of the odometry space (drift keeps it far inside)
ODOM_DRIFT_ALLOWANCE_M = 100.0  # [m] added to the map's diagonal in the goal distance's bound
Information = Literal["map", "sensed"]
StartMode = Literal["listed", "random"]
RESET_OPTIONS = ("task_id", "task_text", "start_pose", "start")


class EnvOptions(BaseModel):
    """What `gymnasium.make(id, **kwargs)` accepts; unknown keys are refused."""

    model_config = ConfigDict(extra="forbid")

    scenario: str
    task_id: str | None = None
    task_text: str | None = None  # free wording; resolved like `llmnav drive --task`
    start_pose: int = Field(default=1, ge=1)  # 1-based, as on the CLI
    start: StartMode = "listed"  # "random": a free pose drawn per reset from the seeded generator
    start_radius_m: float | None = Field(default=None, gt=0)  # [m] random starts this close to the listed one
    information: Information = "sensed"
    sensing: tuple[Literal["lidar", "image", "detections"], ...] = ("lidar", "image", "detections")
    lidar_sectors: int = Field(default=8, ge=1, le=72)
    lidar_fov_deg: float = Field(default=90.0, gt=0, le=360)
    image_width: int = Field(default=160, ge=16, le=640)  # [px]
    image_height: int = Field(default=120, ge=16, le=480)  # [px]
    max_steps: int = Field(default=30, ge=1)
    reward: Literal["score_delta", "progress", "sparse"] = "score_delta"
    observe_goal: bool = False  # the map's target as seen from the odometry pose ("map" information only)
    success_bonus: float = Field(default=1.0, ge=0)
    max_step_m: float = Field(default=5.0, gt=0)  # [m] FRONT/BACK upper bound (Factory)
    control_dt_s: float = Field(default=0.1, gt=0, le=1.0)  # [s] how long a velocity is held
    arrive_radius_m: float = Field(default=0.5, gt=0)  # [m] a stopped velocity agent this close has arrived

    @model_validator(mode="after")
    def _goal_needs_the_map(self) -> EnvOptions:
        if self.observe_goal and self.information != "map":
            raise ValueError("observe_goal needs information='map' (a sensing agent is not told where the target is)")
        return self


def _printable(text: str) -> str:
    """The task text within the `Text` space's charset and length."""
    return "".join(c if c in TASK_CHARSET else "?" for c in text)[:MAX_TASK_CHARS] or "?"


def human_render_problem() -> str | None:
    """Why a window cannot open here (no display, or an OpenCV built without a GUI), or None."""
    if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        return "render_mode='human' needs a display (DISPLAY is not set); use 'rgb_array'"
    # deferred: OpenCV (about 0.13 s) loads only for render_mode='human'
    import cv2

    if "GUI:                           NONE" in cv2.getBuildInformation():
        return (
            "render_mode='human' needs OpenCV with a GUI (llmnav installs the headless build: "
            "pip install opencv-python); use 'rgb_array'"
        )
    return None


class NavEnv(gym.Env[dict[str, Any], Any]):
    """The shared part of llmnav's environments: world, task, observation, reward, info and rendering.

    Subclasses define the action space and `_act`.
    """

    # "human" is declared only where a window can open, so checkers and users are never offered a mode
    # that cannot work on this machine (`render_mode="human"` there raises a clear error instead).
    metadata = {
        "render_modes": ["rgb_array", *(["human"] if human_render_problem() is None else [])],
        "render_fps": 10,
    }

    def __init__(self, render_mode: str | None = None, **kwargs: Any) -> None:
        try:
            self.options = EnvOptions(**kwargs)
        except ValidationError as err:  # a `make` keyword out of range or unknown: one line, not pydantic's page
            raise BadInputError(f"make(): {validation_message(err)}") from None
        self._closed = False
        if render_mode not in (None, "rgb_array", "human"):
            raise BadInputError(f"render_mode {render_mode!r}: use 'rgb_array' or 'human'")
        problem = human_render_problem() if render_mode == "human" else None
        if problem is not None:
            raise BadInputError(problem)
        self.render_mode = render_mode
        self.scenario: Scenario = load_scenario(self.options.scenario)
        self._task_id, self._task_text = self.options.task_id, self.options.task_text
        self.task: Task = self._resolve(self._task_id, self._task_text, self.options.start_pose)
        self.spec_robot = ROBOT_SPECS[self.scenario.robot]
        camera = self.scenario.sensors.camera.model_copy(
            update={"width": self.options.image_width, "height": self.options.image_height}
        )
        self.world: World = World(self.scenario, lidar=self.scenario.sensors.lidar, camera=camera)
        # What actions move the robot with: the raw motion here; `SafetyVeto` puts the guarded layer of
        # llmnav's planners (`llmnav.guard.motion.GuardedMotion`) in its place.
        self.motion: Any = self.world.motion
        self.labels: tuple[str, ...] = tuple(sorted({o.label for o in self.scenario.objects}))
        self.range_m = float(self.scenario.sensors.lidar.range_m)
        self.observation_space = self._observation_space()
        self.start_index = self.options.start_pose
        self.start_mode: StartMode = self.options.start
        self._starts: StartSampler | None = None  # built on the first random start
        self.trajectory: list[list[float]] = []  # true-pose samples [x, y, yaw] since reset (for logs and render)
        self._background: Any = None
        self.last_scan: LidarScan | None = None
        self.last_detections: list[Detection] = []
        self._steps = 0
        self._score = 0.0
        self._progress_distance: float | None = None  # [m] to the best target after the last step
        self._path = 0.0
        self._done = False

    # --- construction helpers ---------------------------------------------------------------------
    def _resolve(self, task_id: str | None, task_text: str | None, start_pose: int) -> Task:
        texts = [task_text] if task_text else None
        if task_id is None and not texts:
            task_id = self.scenario.tasks[0].id if self.scenario.tasks else None
        resolved = resolve_task(self.options.scenario, texts, task_id, start_pose)
        self._start = resolved.start.pose()
        return resolved.task

    def _observation_space(self) -> spaces.Dict:
        o, lidar = self.options, self.world.lidar
        n = o.lidar_sectors
        sector_low = np.tile(np.array([0.0, -math.pi], dtype=np.float32), (n, 1))
        sector_high = np.tile(np.array([self.range_m, math.pi], dtype=np.float32), (n, 1))
        det_max = self._detection_range = max(self.scenario.sensors.detector.max_distance_m, 1.0)
        det_low = np.tile(np.array([-math.pi, 0.0, -1.0], dtype=np.float32), (MAX_DETECTIONS, 1))
        det_high = np.tile(np.array([math.pi, det_max, 1.0], dtype=np.float32), (MAX_DETECTIONS, 1))
        odom = np.array([ODOM_LIMIT_M, ODOM_LIMIT_M, math.pi], dtype=np.float32)
        fields: dict[str, spaces.Space[Any]] = {}
        if "image" in o.sensing:
            fields["image"] = spaces.Box(0, 255, (o.image_height, o.image_width, 3), np.uint8)
        if "lidar" in o.sensing:
            fields["lidar"] = spaces.Box(0.0, self.range_m, (len(lidar.angles),), np.float32)
            fields["sectors"] = spaces.Box(sector_low, sector_high, dtype=np.float32)
        fields["odom"] = spaces.Box(-odom, odom, dtype=np.float32)
        if "detections" in o.sensing:
            fields["detections"] = spaces.Box(det_low, det_high, dtype=np.float32)
            fields["detection_class"] = spaces.MultiDiscrete([len(self.labels) + 1] * MAX_DETECTIONS)
            fields["detection_mask"] = spaces.MultiBinary(MAX_DETECTIONS)
        if o.observe_goal:
            bounds = self.scenario.bounds
            reach = math.hypot(bounds.x[1] - bounds.x[0], bounds.y[1] - bounds.y[0])  # [m] the map's diagonal
            fields["goal"] = spaces.Box(
                np.array([0.0, -1.0, -1.0], dtype=np.float32),
                np.array([reach + ODOM_DRIFT_ALLOWANCE_M, 1.0, 1.0], dtype=np.float32),
                dtype=np.float32,
            )
        fields["task"] = TaskText(MAX_TASK_CHARS, min_length=1, charset=TASK_CHARSET)
        return spaces.Dict(fields)

    # --- the Gymnasium API --------------------------------------------------------------------------
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, Any], dict[str, Any]]:
        """Put the robot at the start pose; `options` may name `task_id`, `task_text`, `start_pose`, `start`.

        `reset(seed=s)` seeds the world's noise streams with s, as `llmnav drive --seed s` does, so it
        repeats observations exactly; an unseeded reset draws the world's seed from the environment's
        generator, continuing the seeded sequence. `start` ("listed" or "random") changes the start mode
        from this reset on; naming `start_pose` alone goes back to the listed start.
        """
        self._check_open()
        names = ", ".join(RESET_OPTIONS)
        if options is not None and not isinstance(options, dict):
            raise BadInputError(f"reset options must be a dict ({names}), not {options!r:.60}")
        super().reset(seed=seed)
        options = dict(options or {})
        unknown = set(options) - set(RESET_OPTIONS)
        if unknown:
            raise BadInputError(f"reset options {sorted(unknown)} are unknown (use {names})")
        if "start" in options:
            if options["start"] not in ("listed", "random"):
                raise BadInputError(f"reset option start={options['start']!r}: use 'listed' or 'random'")
            self.start_mode = options["start"]
        elif "start_pose" in options:
            self.start_mode = "listed"
        if options.keys() - {"start"}:
            if "task_id" in options or "task_text" in options:
                self._task_id, self._task_text = options.get("task_id"), options.get("task_text")
            self.start_index = int(options.get("start_pose", self.start_index))
            self.task = self._resolve(self._task_id, self._task_text, self.start_index)
        # A given seed seeds the world as `llmnav drive --seed` does (the same episode as a planner's);
        # an unseeded reset continues from the environment's generator.
        world_seed = seed if seed is not None else int(self.np_random.integers(0, 2**31 - 1))
        start = self._start
        if self.start_mode == "random":
            if self._starts is None:
                self._starts = StartSampler(self.scenario, self.spec_robot)
            start = self._starts.draw(self.np_random, self._start, self.options.start_radius_m)
        self.world.reset(start, seed=world_seed)
        self.world.motion.on_pose = self._on_pose
        self.trajectory = [start.as_list()]
        self._path = 0.0
        self._steps = 0
        self._rotation = 0.0  # [rad] net turn since reset, and the largest one reached (metrics.total_rotation)
        self._max_rotation = 0.0
        self._done = False
        self._score = self._true_score()
        self._progress_distance = self._distance()
        info = self._info(success=False)
        info["start"] = start.as_list()
        if self.options.information == "map":
            info["map"] = self._published_map()
        return self._observe(), info

    def step(self, action: Any) -> tuple[dict[str, Any], float, bool, bool, dict[str, Any]]:
        """Carry out one action; see the module docstring for reward, termination and info."""
        self._check_open()
        if self._done:
            raise BadInputError("the episode has ended: call reset() before step()")
        finished, result = self._act(action)
        self._steps += 1
        return self._transition(finished, result)

    def render(self) -> np.ndarray | None:
        """`rgb_array`: the top view (trajectory, robot, targets) beside the camera frame."""
        if self.render_mode is None:
            return None
        frame = self._render_frame()
        if self.render_mode == "human":
            # deferred: OpenCV (about 0.13 s) loads only for render_mode='human'
            import cv2

            cv2.imshow("llmnav", cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
            cv2.waitKey(1)
            return None
        return frame

    def _check_open(self) -> None:
        if getattr(self, "_closed", False):
            raise BadInputError("the environment is closed: make a new one")

    def close(self) -> None:
        """Release the physics client (idempotent)."""
        self._closed = True
        world = getattr(self, "world", None)
        if world is not None:
            world.close()
        if self.render_mode == "human":
            # deferred: OpenCV (about 0.13 s) loads only for render_mode='human'
            import cv2

            cv2.destroyAllWindows()

    # --- to override --------------------------------------------------------------------------------
    def _act(self, action: Any) -> tuple[bool, MotionResult | None]:
        """Execute `action`; return (the agent declared the task finished, the motion's result)."""
        raise NotImplementedError

    def _arrived(self) -> bool:
        """Whether the episode ends because the robot reached its target (velocity agents)."""
        return False

    def describe(self, action: Any) -> str:
        """The action as one line for logs (`FRONT 1.5 m`, `v 0.20 m/s, w -0.10 rad/s`)."""
        raise NotImplementedError

    # --- internals ------------------------------------------------------------------------------------
    def _on_pose(self, pose: Pose2D, t_sim: float) -> None:
        # Incremental forms of metrics.path_length and metrics.total_rotation over the same samples.
        x, y, yaw = self.trajectory[-1]
        self._path += math.hypot(pose.x - x, pose.y - y)
        self._rotation += wrap_angle(pose.yaw - yaw)
        self._max_rotation = max(self._max_rotation, abs(self._rotation))
        self.trajectory.append(pose.as_list())

    def _transition(
        self, finished: bool, result: MotionResult | None
    ) -> tuple[dict[str, Any], float, bool, bool, dict[str, Any]]:
        pose = self.world.robot.pose()
        self._on_pose(pose, self.world.sim_time)
        score = self._true_score()
        terminated = finished or self._arrived()
        truncated = not terminated and self._steps >= self.options.max_steps
        success = terminated and self._success()
        reward = self._shaping(score) + (self.options.success_bonus if success else 0.0)
        self._score = score
        self._done = terminated or truncated
        info = self._info(success=success)
        if result is not None and result.collided:
            info["collided_with"] = result.collision_with
        if result is not None and result.veto is not None:
            info["vetoed"] = result.veto
        return self._observe(), reward, terminated, truncated, info

    def _shaping(self, score: float) -> float:
        """The reward's dense part for this step (the module docstring's `reward`)."""
        kind = self.options.reward
        if kind == "sparse":
            return 0.0
        distance = self._distance()
        if kind == "progress" and distance is not None and self._progress_distance is not None:
            gained = self._progress_distance - distance  # [m] nearer the target than a step ago
            self._progress_distance = distance
            return float(gained)
        return float(score - self._score)

    def _targets(self) -> list[tuple[float, float]]:
        return [tuple(p) for p in self.scenario.target_points(self.task)]  # type: ignore[misc]

    def _true_score(self) -> float:
        """S of the true pose (ground truth: for the reward only, never observed)."""
        if self.task.kind == "rotate":
            return 1.0 if rotation_done(self._max_rotation) else 0.0
        best = best_target(self.world.robot.pose(), self._targets())
        return best.score if best is not None else 0.0

    def _distance(self) -> float | None:
        best = best_target(self.world.robot.pose(), self._targets())
        return best.distance_m if best is not None else None

    def _success(self) -> bool:
        if self.task.kind == "rotate":
            return rotation_done(self._max_rotation)
        if self.task.kind == "explore":
            return True
        distance = self._distance()
        return distance is not None and distance <= SUCCESS_RADIUS_M

    def _info(self, *, success: bool) -> dict[str, Any]:
        distance = self._distance()
        return {
            "score": round(self._score, 6),
            "distance_m": None if distance is None else round(distance, 6),
            "success": success,
            "path_length_m": round(self._path, 6),
            "collisions": self.world.motion.collisions,
            "sim_time_s": round(self.world.sim_time, 6),
            "steps": self._steps,
            "information": self.options.information,
        }

    def _published_map(self) -> dict[str, Any]:
        return {
            "corridors": [c.model_dump(mode="json") for c in self.scenario.corridors],
            "objects": [
                {"id": o.id, "label": o.label, "center": list(o.center), "goal": list(o.goal_point)}
                for o in self.scenario.objects
            ],
        }

    def _observe(self) -> dict[str, Any]:
        """Read the sensors. The LiDAR is always scanned (the veto judges every action on it)."""
        world, sensing = self.world, self.options.sensing
        scan = world.lidar.scan()
        self.last_scan = scan
        frame = None
        if "image" in sensing:
            # At the detector's own resolution one render with the mask serves both: the same pixels and
            # detections as two renders, in little more than half the time (rendering is most of a step).
            shared = "detections" in sensing and (self.options.image_width, self.options.image_height) == DETECTOR_SIZE
            frame = world.camera.capture(segmentation=shared)
        self.last_detections = world.detector.detect(frame) if "detections" in sensing else []
        obs: dict[str, Any] = {}
        if frame is not None:
            obs["image"] = np.ascontiguousarray(frame.rgb, dtype=np.uint8).copy()
        if "lidar" in sensing:
            ranges = np.where(np.isfinite(scan.ranges), scan.ranges, self.range_m)
            obs["lidar"] = np.clip(ranges, 0.0, self.range_m).astype(np.float32)
            obs["sectors"] = self._sector_table(scan)
        odom = world.robot.odom()
        obs["odom"] = np.array([odom.x, odom.y, wrap_angle(odom.yaw)], dtype=np.float32)
        if "detections" in sensing:
            obs.update(self._detection_table(self.last_detections))
        if self.options.observe_goal:
            obs["goal"] = self._goal_vector(odom)
        obs["task"] = _printable(self.task.text)
        return obs

    def _goal_vector(self, odom: Pose2D) -> np.ndarray:
        """(distance [m], sin, cos of the bearing) of the map's nearest target point from the odometry pose."""
        points = self._targets()
        if not points:
            return np.zeros(3, dtype=np.float32)
        x, y = min(points, key=lambda p: math.hypot(p[0] - odom.x, p[1] - odom.y))
        bearing = odom.bearing_to(x, y)
        return np.array([math.hypot(x - odom.x, y - odom.y), math.sin(bearing), math.cos(bearing)], dtype=np.float32)

    def _sector_table(self, scan: LidarScan) -> np.ndarray:
        sectors = lidar_sectors(scan, self.options.lidar_sectors, self.options.lidar_fov_deg)
        table = np.zeros((len(sectors), 2), dtype=np.float32)
        for i, s in enumerate(sectors):
            table[i, 0] = min(s.min_m, self.range_m)
            centre = (s.start_deg + s.end_deg) / 2.0
            table[i, 1] = math.radians(s.min_angle_deg if s.min_angle_deg is not None else centre)
        return table

    def _detection_table(self, detections: list[Detection]) -> dict[str, np.ndarray]:
        rows = np.zeros((MAX_DETECTIONS, 3), dtype=np.float32)
        classes = np.zeros(MAX_DETECTIONS, dtype=np.int64)
        mask = np.zeros(MAX_DETECTIONS, dtype=np.int8)
        for i, d in enumerate(sorted(detections, key=lambda d: d.distance_m)[:MAX_DETECTIONS]):
            rows[i] = (wrap_angle(math.radians(d.bearing_deg)), min(d.distance_m, self._detection_range), d.offset)
            classes[i] = self.labels.index(d.label) + 1
            mask[i] = 1
        return {"detections": rows, "detection_class": classes, "detection_mask": mask}

    def _render_frame(self) -> np.ndarray:
        """Top view (drawn once with llmnav's scenario drawing, then the robot per frame) + camera."""
        # deferred: OpenCV (about 0.13 s) loads only when a frame is rendered
        import cv2

        if self._background is None:
            self._background = raster_scenario(self.scenario, self._targets())
        image, to_px = self._background
        top = image.copy()
        points = np.array([to_px(p[0], p[1]) for p in self.trajectory], dtype=np.int32)
        if len(points) > 1:
            cv2.polylines(top, [points.reshape(-1, 1, 2)], False, (214, 39, 40), 2)
        pose = self.world.robot.pose()
        cx, cy = to_px(pose.x, pose.y)
        nose = to_px(pose.x + 0.5 * math.cos(pose.yaw), pose.y + 0.5 * math.sin(pose.yaw))
        cv2.circle(top, (cx, cy), 6, (31, 119, 180), -1)
        cv2.line(top, (cx, cy), nose, (31, 119, 180), 2)
        camera = self.world.camera.capture().rgb
        height = top.shape[0]
        scale = height / camera.shape[0]
        camera = cv2.resize(camera, (max(1, round(camera.shape[1] * scale)), height))
        return np.ascontiguousarray(np.concatenate([top, camera], axis=1), dtype=np.uint8)


class FactoryEnv(NavEnv):
    """The stepwise source's protocol: one discrete action per step.

    Action: `Dict(command=Discrete(5), distance_m=Box(0, max_step_m), angle_deg=Box(0, 360))`. `command`
    indexes `COMMANDS` (FRONT, BACK, ROTATE_LEFT, ROTATE_RIGHT, COMPLETE); FRONT/BACK move `distance_m`
    [m] and the rotations turn `angle_deg` [deg] (left = counter-clockwise); the field a command does not
    use is ignored. COMPLETE ends the episode (`terminated`).
    """

    COMMANDS: ClassVar[tuple[str, ...]] = ("FRONT", "BACK", "ROTATE_LEFT", "ROTATE_RIGHT", "COMPLETE")

    def __init__(self, render_mode: str | None = None, **kwargs: Any) -> None:
        kwargs.setdefault("scenario", "factory")
        super().__init__(render_mode, **kwargs)
        self.action_space = spaces.Dict(
            {
                "command": spaces.Discrete(len(self.COMMANDS)),
                "distance_m": spaces.Box(0.0, self.options.max_step_m, (1,), np.float32),
                "angle_deg": spaces.Box(0.0, 360.0, (1,), np.float32),
            }
        )

    @staticmethod
    def decode(action: Any) -> tuple[str, float]:
        """(command name, signed motion): metres for FRONT/BACK (BACK negative), radians for turns (right negative)."""
        command = FactoryEnv.COMMANDS[int(action["command"])]
        distance = float(np.asarray(action["distance_m"]).reshape(-1)[0])
        angle = math.radians(float(np.asarray(action["angle_deg"]).reshape(-1)[0]))
        return command, {
            "FRONT": distance,
            "BACK": -distance,
            "ROTATE_LEFT": angle,
            "ROTATE_RIGHT": -angle,
            "COMPLETE": 0.0,
        }[command]

    def describe(self, action: Any) -> str:
        """`FRONT 1.5 m`, `ROTATE_LEFT 30°`, `COMPLETE`."""
        command, amount = self.decode(action)
        if command in ("FRONT", "BACK"):
            return f"{command} {abs(amount):g} m"
        if command == "COMPLETE":
            return command
        return f"{command} {math.degrees(abs(amount)):g}°"

    def _act(self, action: Any) -> tuple[bool, MotionResult | None]:
        if action not in self.action_space:
            raise BadInputError(f"action {action!r} is not in the action space {self.action_space}")
        command, amount = self.decode(action)
        motion = self.motion
        if command == "COMPLETE":
            return True, None
        if command in ("FRONT", "BACK"):
            return False, motion.drive(amount) if amount else None
        return False, motion.rotate(amount) if amount else None


class VelocityEnv(NavEnv):
    """Continuous control: a velocity command held for one control period.

    Action: `Box([-v_max, -w_max], [v_max, w_max])`, (v [m/s], w [rad/s]) within the robot's kinematic
    limits, held for `control_dt_s` of simulated time. The episode ends (`terminated`) when the robot has
    stopped (|v| and |w| below 1 % of their limits) within `arrive_radius_m` of a target.
    """

    def __init__(self, render_mode: str | None = None, **kwargs: Any) -> None:
        super().__init__(render_mode, **kwargs)
        limit = np.array([self.spec_robot.max_linear, self.spec_robot.max_angular], dtype=np.float32)
        self.action_space = spaces.Box(-limit, limit, dtype=np.float32)
        self._last_command = (0.0, 0.0)

    def _command(self, action: Any) -> tuple[float, float]:
        """(v [m/s], w [rad/s]) of an action in the space, judged in the space's own precision (float32).

        The space's float32 bounds lie a rounding beyond the robot's limits (0.4 m/s is 0.40000000596 in
        float32): an action at the bound is the limit itself, so it is clipped onto the exact limits here
        and the safety layer never mistakes float32 rounding for a command out of its kinematic box.
        """
        command = np.asarray(action, dtype=np.float32).reshape(-1)
        if command.shape != (2,) or command not in self.action_space:
            raise BadInputError(f"action {action!r} is not in the action space {self.action_space}")
        v_max, w_max = self.spec_robot.max_linear, self.spec_robot.max_angular
        return min(max(float(command[0]), -v_max), v_max), min(max(float(command[1]), -w_max), w_max)

    def describe(self, action: Any) -> str:
        """`v 0.20 m/s, w -0.10 rad/s`."""
        v, w = self._command(action)
        return f"v {v:.3f} m/s, w {w:.3f} rad/s"

    def _act(self, action: Any) -> tuple[bool, MotionResult | None]:
        v, w = self._command(action)
        self._last_command = (v, w)
        return False, self.motion.velocity_tick(v, w, self.options.control_dt_s)

    def _arrived(self) -> bool:
        v, w = self._last_command
        still = abs(v) <= 0.01 * self.spec_robot.max_linear and abs(w) <= 0.01 * self.spec_robot.max_angular
        distance = self._distance()
        return still and distance is not None and distance <= self.options.arrive_radius_m
