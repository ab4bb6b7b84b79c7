"""Scenario files: the world, its labelled objects, tasks and start poses, validated with pydantic.

A scenario is a YAML file in `scenarios/` (or any path). Every error is reported as one line naming the
file, the path inside it and the problem, raised as `ScenarioError` (exit code 2 in the CLI).
Units: metres, degrees in files (yaw_deg), radians in code.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from functools import lru_cache
from pathlib import Path
from typing import Annotated, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from llmnav.core.geometry import Pose2D
from llmnav.core.resources import resource_dir
from llmnav.core.robot_specs import ROBOT_SPECS
from llmnav.errors import BadInputError, ScenarioError

RGBA = tuple[float, float, float, float]
Vec2 = tuple[float, float]

# What a scenario may hold. The largest bundled world is 20 m x 30 m with 50 shapes; the limits leave
# room for far bigger ones and keep every grid, plot and prompt built from a scenario in memory and time:
# a 100 m side is 2,000 cells of the 5 cm planning grid, where ±1e6 m asked for 1.42 PiB.
MAX_WORLD_SIDE_M = 100.0  # [m] each side of `bounds`
MAX_COORDINATE_M = 1000.0  # [m] |x| and |y| of `bounds` (float precision of poses stays sub-millimetre)
# walls + obstacles: each a static body (cheap in maximal coordinates: 1,200 boxes of an imported nav2 map
# step in 0.15 ms) and a plot patch
MAX_SHAPES = 5000
MAX_OBJECTS = 500  # labelled objects: each also a label in plots, menus and the detector's bookkeeping
MAX_TASKS = 200  # tasks in one file
MAX_TEXT_CHARS = 2000  # [characters] a task's text or paraphrase (a prompt carries it at every step)
MAX_NAME_CHARS = 100  # [characters] an object's label or alias (scored as a continuation, token by token)
Name = Annotated[str, Field(min_length=1, max_length=MAX_NAME_CHARS)]


class _Strict(BaseModel):
    # NaN and infinity are refused at load: a size of .nan passed `scenarios show` and crashed the grid
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class _Physical(_Strict):
    """A block of physical parameters: NaN and infinities are rejected like any out-of-range value."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class Shape(_Strict):
    """A box or cylinder footprint standing on the floor (or lifted by `z`)."""

    shape: Literal["box", "cylinder"] = "box"
    center: Vec2  # [m] world frame
    size: Vec2 | None = None  # [m] box footprint (x, y) before yaw
    radius: float | None = Field(default=None, gt=0)  # [m] cylinder
    height: float = Field(default=1.0, gt=0)  # [m]
    z: float = Field(default=0.0, ge=0)  # [m] bottom elevation (wall plates, signs)
    yaw_deg: float = 0.0  # [deg]
    color: RGBA = (0.6, 0.6, 0.6, 1.0)
    solid: bool = True  # False: visible to the camera, but the robot and LiDAR pass through it

    @model_validator(mode="after")
    def _dims(self) -> Shape:
        if self.shape == "box" and self.size is None:
            raise ValueError("a box needs 'size: [sx, sy]'")
        if self.shape == "cylinder" and self.radius is None:
            raise ValueError("a cylinder needs 'radius'")
        if self.size is not None and min(self.size) <= 0:
            raise ValueError("size must be positive")
        return self

    @property
    def yaw(self) -> float:
        """Yaw [rad]."""
        return math.radians(self.yaw_deg)

    def half_extents(self) -> Vec2:
        """Axis-aligned half extents [m] of the footprint's bounding box (yaw taken into account)."""
        if self.shape == "cylinder":
            assert self.radius is not None
            return (self.radius, self.radius)
        assert self.size is not None
        c, s = abs(math.cos(self.yaw)), abs(math.sin(self.yaw))
        sx, sy = self.size[0] / 2, self.size[1] / 2
        return (c * sx + s * sy, s * sx + c * sy)

    def contains(self, x: float, y: float, inflate: float = 0.0) -> bool:
        """Whether a point lies inside the footprint grown by `inflate` [m]."""
        dx, dy = x - self.center[0], y - self.center[1]
        if self.shape == "cylinder":
            assert self.radius is not None
            return math.hypot(dx, dy) <= self.radius + inflate
        assert self.size is not None
        c, s = math.cos(-self.yaw), math.sin(-self.yaw)
        lx, ly = c * dx - s * dy, s * dx + c * dy
        return abs(lx) <= self.size[0] / 2 + inflate and abs(ly) <= self.size[1] / 2 + inflate

    def distance_to(self, x: float, y: float) -> float:
        """Distance [m] from a point to the footprint boundary (0 inside)."""
        dx, dy = x - self.center[0], y - self.center[1]
        if self.shape == "cylinder":
            assert self.radius is not None
            return max(0.0, math.hypot(dx, dy) - self.radius)
        assert self.size is not None
        c, s = math.cos(-self.yaw), math.sin(-self.yaw)
        lx, ly = abs(c * dx - s * dy) - self.size[0] / 2, abs(s * dx + c * dy) - self.size[1] / 2
        return math.hypot(max(lx, 0.0), max(ly, 0.0))


class Obstacle(Shape):
    """A static, unlabelled obstacle or wall."""

    id: str | None = None


class LabelledObject(Shape):
    """An object that tasks and detections name."""

    id: Annotated[str, Field(pattern=r"^[A-Za-z0-9_.-]+$", max_length=MAX_NAME_CHARS)]
    label: Name
    aliases: list[Name] = []
    # Where a robot should stand to "reach" it, when that differs from the centre (a room plate on a wall).
    goal: Vec2 | None = None
    sign: Literal["left", "right", "stop"] | None = None  # traffic-sign class for the FSM detector

    @property
    def goal_point(self) -> Vec2:
        """The point distances to this object are measured to [m]."""
        return self.goal if self.goal is not None else self.center

    def names(self) -> list[str]:
        """Label, aliases and id, lower-cased, for name matching."""
        return [n.lower() for n in (self.label, *self.aliases, self.id)]


class Target(_Strict):
    """An acceptable target of a task: a labelled object id or a free point."""

    object: str | None = None
    point: Vec2 | None = None

    @model_validator(mode="after")
    def _one(self) -> Target:
        if (self.object is None) == (self.point is None):
            raise ValueError("a target is either 'object: ID' or 'point: [x, y]'")
        return self


class StartPose(_Strict):
    """A start pose: x, y [m], yaw [deg]."""

    x: float
    y: float
    yaw_deg: float = 0.0

    def pose(self) -> Pose2D:
        """As a Pose2D (radians)."""
        return Pose2D(self.x, self.y, math.radians(self.yaw_deg))


# A sequence of commands as one task's text (`llmnav drive --task A --task B`, a route): its legs joined by this.
SEQUENCE_JOIN = "; then "


class RouteLeg(_Strict):
    """One command of a route: its text and acceptable targets. It starts where the previous leg ended."""

    text: Annotated[str, Field(min_length=1, max_length=MAX_TEXT_CHARS)]
    targets: Annotated[list[Target], Field(min_length=1)]

    @field_validator("text")
    @classmethod
    def _no_join(cls, text: str) -> str:
        if SEQUENCE_JOIN in text:
            raise ValueError(f"a leg's text may not contain {SEQUENCE_JOIN!r} (it joins the legs of a route)")
        return text


class Task(_Strict):
    """A task: its exact text, acceptable targets, kind, difficulty and start poses.

    `paraphrases` are other wordings of the same task, as people would say them (same targets and start
    poses); `wording` says which wording `text` is: "bundled" (the scenario's), "paraphrase:<k>" (1-based)
    or "free" (typed by a user). Files leave `wording` out; `llmnav.world.tasks` sets it.
    """

    id: Annotated[str, Field(max_length=MAX_NAME_CHARS)]
    text: Annotated[str, Field(max_length=MAX_TEXT_CHARS)]
    kind: Literal["target", "explore", "rotate"] = "target"
    difficulty: Literal["easy", "medium", "hard"] = "medium"
    targets: list[Target] = []
    start_poses: list[StartPose] = []
    paraphrases: list[Annotated[str, Field(min_length=1, max_length=MAX_TEXT_CHARS)]] = []
    wording: Annotated[str, Field(pattern=r"^(bundled|free|paraphrase:[1-9][0-9]*)$")] = "bundled"
    legs: list[RouteLeg] = []  # a route's commands in order (`Route.as_task`); empty for a single command

    @model_validator(mode="after")
    def _targets(self) -> Task:
        if self.kind == "target" and not self.targets:
            raise ValueError("a 'target' task needs at least one target")
        texts = [" ".join(t.lower().split()) for t in (self.text, *self.paraphrases)]
        if len(set(texts)) != len(texts):
            raise ValueError("a paraphrase repeats the task text or another paraphrase")
        return self


class Route(_Strict):
    """Commands driven one after another in one episode, each leg starting where the last one ended.

    The waypoint source ran its environments this way (SP → window, window → room 105, ...) and reported
    every leg as a row. `--task-id ID` runs a route like a task (`as_task`); each leg is scored on its own
    (`llmnav score --table waypoints-legs`), the episode succeeds when the last leg's target is reached.
    """

    id: Annotated[str, Field(min_length=1, max_length=MAX_NAME_CHARS)]
    description: Annotated[str, Field(max_length=MAX_TEXT_CHARS)] = ""
    difficulty: Literal["easy", "medium", "hard"] = "medium"
    start: StartPose
    legs: Annotated[list[RouteLeg], Field(min_length=1, max_length=MAX_TASKS)]

    def as_task(self) -> Task:
        """The route as one task: its legs' texts joined, the last leg's targets, its start pose."""
        return Task(
            id=self.id,
            text=SEQUENCE_JOIN.join(leg.text for leg in self.legs),
            kind="target",
            difficulty=self.difficulty,
            targets=list(self.legs[-1].targets),
            start_poses=[self.start],
            legs=list(self.legs),
        )


class Corridor(_Strict):
    """An axis-aligned corridor rectangle, the free space the waypoint planner may use."""

    id: str
    x: Vec2  # [m] (min, max)
    y: Vec2  # [m] (min, max)

    @model_validator(mode="after")
    def _order(self) -> Corridor:
        if self.x[0] >= self.x[1] or self.y[0] >= self.y[1]:
            raise ValueError("corridor ranges must be (min, max) with min < max")
        return self

    def contains(self, x: float, y: float, margin: float = 0.0) -> bool:
        """Whether (x, y) lies inside the rectangle shrunk by `margin` [m]."""
        return (self.x[0] + margin <= x <= self.x[1] - margin) and (self.y[0] + margin <= y <= self.y[1] - margin)


class LidarConfig(_Physical):
    """2D LiDAR defaults; `noise_std_m` [m] is the std of the Gaussian range noise of each ray."""

    fov_deg: float = Field(default=360.0, gt=0, le=360)
    rays: int = Field(default=360, ge=8, le=4096)
    range_m: float = Field(default=10.0, gt=0)
    min_range_m: float = Field(default=0.05, ge=0)
    mount_height_m: float = Field(default=0.25, gt=0)
    noise_std_m: float = Field(default=0.0, ge=0)


class CameraConfig(_Strict):
    """RGB camera defaults (at most 640x480, as the stepwise source sends)."""

    width: int = Field(default=640, ge=16, le=640)
    height: int = Field(default=480, ge=16, le=480)
    fov_deg: float = Field(default=60.0, gt=10, lt=170)  # vertical field of view
    mount_height_m: float = Field(default=1.0, gt=0)
    far_m: float = Field(default=25.0, gt=1)
    jpeg_quality: int = Field(default=80, ge=10, le=100)


class DetectorConfig(_Physical):
    """The object detector: which labelled objects it reports, and the errors of what it reports.

    An object is a candidate when it covers at least `min_pixels` of the detector's 160x120 segmentation
    frame (so walls in front of it hide it), lies within `max_distance_m` and, with `occlusion: center`,
    its centre is in the camera's line of sight (a ray test: a detector that only sees an edge of a sign
    cannot localise it). Each candidate is then missed with probability `dropout` per frame.

    Distance readings at true range d: d * (1 + distance_bias) + N(0, sigma(d)^2), with
    sigma(d) = distance_noise_std_m + distance_noise_per_m * d (a constant part, e.g. box jitter, and a
    part growing with range, as monocular range-from-size does), drawn afresh each frame.
    Bearing readings: the true bearing + N(0, bearing_noise_std_deg^2); the image offset is shifted by the
    same angle. The defaults are an ideal detector; every bundled scenario sets its own errors.
    """

    min_pixels: int = Field(default=30, ge=1)  # [px] at 160x120, scaled to the frame's resolution
    max_distance_m: float = Field(default=12.0, gt=0)  # [m] maximum range of a detection
    occlusion: Literal["mask", "center"] = "mask"  # "center": also needs a clear ray to the object's centre
    distance_noise_std_m: float = Field(default=0.0, ge=0, le=10)  # [m] constant part of sigma(d)
    distance_noise_per_m: float = Field(default=0.0, ge=0, le=1)  # [m/m] growth of sigma(d) with range
    distance_bias: float = Field(default=0.0, gt=-1, lt=1)  # [-] relative bias (+0.05: reads 5 % long)
    bearing_noise_std_deg: float = Field(default=0.0, ge=0, le=45)  # [deg]
    dropout: float = Field(default=0.0, ge=0, le=1)  # [-] probability a candidate is missed in a frame

    def distance_sigma(self, distance_m: float) -> float:
        """Standard deviation [m] of a distance reading at true range `distance_m` [m]."""
        return self.distance_noise_std_m + self.distance_noise_per_m * distance_m

    @property
    def ideal(self) -> bool:
        """Whether readings are exact (no noise, bias or dropout)."""
        return (
            self.distance_noise_std_m == 0
            and self.distance_noise_per_m == 0
            and self.distance_bias == 0
            and self.bearing_noise_std_deg == 0
            and self.dropout == 0
        )


class OdometryConfig(_Physical):
    """Wheel odometry errors (see `llmnav.sim.robot`), per wheel as encoders see them.

    Systematic, drawn once per episode from its seed: each wheel's effective radius is off by a relative
    N(0, wheel_scale_std^2) (distance scale error and a steady curve), the effective track width by
    N(0, track_scale_std^2) (every measured turn too large or too small). Random: each wheel's measured
    travel gets N(0, wheel_noise_m_per_sqrt_m^2 * |travel|), a random walk that grows with the square root
    of the distance the wheel rolled (slip, uneven floor). All zeros (the class default, like the ideal
    detector) makes odometry exact; the bundled worlds without a published map (factory, maze) turn drift
    on in their files, `typical()` gives those values. Scoring never uses odometry, only the true pose.
    """

    wheel_scale_std: float = Field(default=0.0, ge=0, le=0.2)  # [-] relative, per wheel
    track_scale_std: float = Field(default=0.0, ge=0, le=0.2)  # [-] relative
    wheel_noise_m_per_sqrt_m: float = Field(default=0.0, ge=0, le=0.5)  # [m/sqrt(m)]

    @classmethod
    def exact(cls) -> OdometryConfig:
        """Odometry equal to the true motion."""
        return cls(wheel_scale_std=0.0, track_scale_std=0.0, wheel_noise_m_per_sqrt_m=0.0)

    @classmethod
    def typical(cls) -> OdometryConfig:
        """A small differential base on a clean floor (the factory's and the maze's setting)."""
        return cls(wheel_scale_std=0.002, track_scale_std=0.01, wheel_noise_m_per_sqrt_m=0.005)

    @property
    def is_exact(self) -> bool:
        """Whether this configuration adds no error at all."""
        return self.wheel_scale_std == 0 and self.track_scale_std == 0 and self.wheel_noise_m_per_sqrt_m == 0


class SensorConfig(_Strict):
    """Sensor defaults of a scenario."""

    lidar: LidarConfig = LidarConfig()
    # A second planar scanner just above the floor, as safety scanners are mounted: it sees what lies below
    # the LiDAR's plane (a pallet, a step, a low table) for the collision monitor, the motion checks and
    # the planners' maps. Short range: it only has to see what the robot could reach soon.
    low_lidar: LidarConfig = LidarConfig(rays=360, range_m=3.0, mount_height_m=0.06)
    camera: CameraConfig = CameraConfig()
    detector: DetectorConfig = DetectorConfig()
    odometry: OdometryConfig = OdometryConfig()


class WaypointRules(_Strict):
    """The waypoint planner's rules for this environment (source B)."""

    margin_m: float = 0.5
    spacing_m: float = 0.7
    target_tolerance_m: float = 0.05
    max_waypoints: int = Field(default=6, ge=1)


class Bounds(_Strict):
    """The world's axis-aligned extent [m].

    Each side positive and at most MAX_WORLD_SIDE_M, every coordinate within ±MAX_COORDINATE_M.
    """

    x: Vec2
    y: Vec2

    @model_validator(mode="after")
    def _extent(self) -> Bounds:
        for axis, (low, high) in (("x", self.x), ("y", self.y)):
            if max(abs(low), abs(high)) > MAX_COORDINATE_M:
                raise ValueError(f"{axis} {[low, high]} reaches beyond ±{MAX_COORDINATE_M:g} m")
            if not low < high:
                raise ValueError(f"{axis} {[low, high]} is empty: the first value must be the smaller")
            if high - low > MAX_WORLD_SIDE_M:
                raise ValueError(f"{axis} spans {high - low:g} m, more than the {MAX_WORLD_SIDE_M:g} m a world may")
        return self

    def contains(self, x: float, y: float) -> bool:
        """Whether a point lies inside."""
        return self.x[0] <= x <= self.x[1] and self.y[0] <= y <= self.y[1]


class Scenario(_Strict):
    """A complete scenario: the world, labelled objects, tasks and defaults.

    Limits (the module's constants): bounds of at most MAX_WORLD_SIDE_M a side within ±MAX_COORDINATE_M,
    at most MAX_SHAPES walls and obstacles together and MAX_OBJECTS labelled objects, MAX_TASKS tasks,
    MAX_TEXT_CHARS a task text and MAX_NAME_CHARS a label or alias.
    """

    name: str
    description: str = ""
    robot: Literal["pr2", "burger", "pr2-square"] = "pr2"
    bounds: Bounds
    floor_color: RGBA = (0.55, 0.55, 0.5, 1.0)
    wall_height: float = Field(default=2.5, gt=0)
    walls: list[Obstacle] = []
    obstacles: list[Obstacle] = []
    objects: list[LabelledObject] = []
    corridors: list[Corridor] = []
    # Whether planners are handed the map (llmnav.world.knowledge); None: "map" where corridors are listed.
    default_information: Literal["map", "sensed"] | None = None
    tasks: Annotated[list[Task], Field(max_length=MAX_TASKS)] = []
    routes: Annotated[list[Route], Field(max_length=MAX_TASKS)] = []
    default_start: StartPose = StartPose(x=0.0, y=0.0)
    sensors: SensorConfig = SensorConfig()
    waypoint_rules: WaypointRules = WaypointRules()

    @model_validator(mode="after")
    def _shape_count(self) -> Scenario:
        count = len(self.walls) + len(self.obstacles)
        if count > MAX_SHAPES:
            raise ValueError(f"{count} walls and obstacles: at most {MAX_SHAPES}")
        if len(self.objects) > MAX_OBJECTS:
            raise ValueError(f"{len(self.objects)} labelled objects: at most {MAX_OBJECTS}")
        return self

    @field_validator("objects")
    @classmethod
    def _unique_ids(cls, objects: list[LabelledObject]) -> list[LabelledObject]:
        seen: set[str] = set()
        for obj in objects:
            if obj.id in seen:
                raise ValueError(f"duplicate object id '{obj.id}'")
            seen.add(obj.id)
        return objects

    # --- look-ups -------------------------------------------------------------------------------
    def object(self, object_id: str) -> LabelledObject:
        """The labelled object with this id (KeyError if absent)."""
        for obj in self.objects:
            if obj.id == object_id:
                return obj
        raise KeyError(object_id)

    def task(self, task_id: str) -> Task:
        """The task with this id, or the route with it as a task (KeyError if neither)."""
        for task in self.tasks:
            if task.id.lower() == task_id.lower():
                return task
        for route in self.routes:
            if route.id.lower() == task_id.lower():
                return route.as_task()
        raise KeyError(task_id)

    def solid_shapes(self) -> list[Shape]:
        """Everything the robot can collide with: walls, obstacles and solid labelled objects."""
        return [*self.walls, *self.obstacles, *(o for o in self.objects if o.solid)]

    def target_points(self, task: Task) -> list[Vec2]:
        """The goal points of a task's acceptable targets."""
        return [self.object(t.object).goal_point if t.object else t.point for t in task.targets]  # type: ignore[misc]

    def start_poses(self, task: Task | None) -> list[StartPose]:
        """A task's start poses, or the scenario default."""
        return list(task.start_poses) if task is not None and task.start_poses else [self.default_start]


# --- loading ------------------------------------------------------------------------------------


def _loc(loc: tuple[int | str, ...]) -> str:
    out = ""
    for part in loc:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out or "(top level)"


def _start_problem(sc: Scenario, start: StartPose, radius_m: float, solids: Sequence[Shape]) -> str | None:
    """Why a start pose is unusable (outside the bounds, the robot's footprint on something solid), or None."""
    if not sc.bounds.contains(start.x, start.y):
        return f"start pose ({start.x}, {start.y}) is outside bounds"
    if any(s.contains(start.x, start.y, inflate=radius_m) for s in solids):
        return f"start pose ({start.x}, {start.y}) overlaps an obstacle"
    return None


def _check_consistency(sc: Scenario) -> list[tuple[str, str]]:
    """Cross-field checks pydantic cannot express; returns (path, problem) pairs."""
    problems: list[tuple[str, str]] = []
    ids = {o.id for o in sc.objects}
    for i, obj in enumerate(sc.objects):
        if not sc.bounds.contains(*obj.center):
            problems.append((f"objects[{i}].center", f"object '{obj.id}' at {list(obj.center)} is outside bounds"))
    for i, obs in enumerate(sc.obstacles):
        if not sc.bounds.contains(*obs.center):
            problems.append((f"obstacles[{i}].center", f"obstacle at {list(obs.center)} is outside bounds"))
    # A start pose must leave the robot's footprint clear of everything solid.
    radius = ROBOT_SPECS[sc.robot].radius_m
    solids = sc.solid_shapes()
    for ti, task in enumerate(sc.tasks):
        for tj, target in enumerate(task.targets):
            if target.object is not None and target.object not in ids:
                problems.append((f"tasks[{ti}].targets[{tj}].object", f"unknown target id '{target.object}'"))
        for si, start in enumerate(task.start_poses):
            problem = _start_problem(sc, start, radius, solids)
            if problem:
                problems.append((f"tasks[{ti}].start_poses[{si}]", problem))
    task_ids = {t.id.lower() for t in sc.tasks}
    for ri, route in enumerate(sc.routes):
        if route.id.lower() in task_ids:
            problems.append((f"routes[{ri}].id", f"route id '{route.id}' is also a task id"))
        for li, leg in enumerate(route.legs):
            for tj, target in enumerate(leg.targets):
                if target.object is not None and target.object not in ids:
                    where = f"routes[{ri}].legs[{li}].targets[{tj}].object"
                    problems.append((where, f"unknown target id '{target.object}'"))
        problem = _start_problem(sc, route.start, radius, solids)
        if problem:
            problems.append((f"routes[{ri}].start", problem))
    start = sc.default_start
    if any(s.contains(start.x, start.y, inflate=radius) for s in solids):
        problems.append(("default_start", f"start pose ({start.x}, {start.y}) overlaps an obstacle"))
    return problems


def consistency_problems(scenario: Scenario) -> list[tuple[str, str]]:
    """Every cross-field problem of a validated scenario as (path, problem) pairs (`parse_scenario` raises one)."""
    return _check_consistency(scenario)


def parse_scenario(data: object, source: str) -> Scenario:
    """Validate already-loaded YAML data; `source` names the file in error messages."""
    if not isinstance(data, dict):
        raise ScenarioError(f"{source}: (top level): expected a mapping, got {type(data).__name__}")
    try:
        scenario = Scenario.model_validate(data)
    except ValidationError as err:
        first = err.errors()[0]
        msg = first["msg"].removeprefix("Value error, ")
        more = f" (+{err.error_count() - 1} more)" if err.error_count() > 1 else ""
        raise ScenarioError(f"{source}: {_loc(tuple(first['loc']))}: {msg}{more}") from None
    problems = _check_consistency(scenario)
    if problems:
        path, msg = problems[0]
        more = f" (+{len(problems) - 1} more)" if len(problems) > 1 else ""
        raise ScenarioError(f"{source}: {path}: {msg}{more}")
    return scenario


def scenario_dir() -> Path:
    """The folder holding the bundled scenario files."""
    return resource_dir("scenarios")


def list_scenarios() -> list[str]:
    """Names of the bundled scenarios."""
    return sorted(p.stem for p in scenario_dir().glob("*.yaml"))


def check_added_obstacles(
    scenario: Scenario, start: tuple[float, float], obstacles: Sequence[tuple[float, float]], clearance: float
) -> None:
    """Refuse obstacles dropped outside the world or within `clearance` [m] of the start position."""
    b = scenario.bounds
    for x, y in obstacles:
        where = f"--obstacle {x:g},{y:g}"
        if not (math.isfinite(x) and math.isfinite(y)):
            raise BadInputError(f"{where}: coordinates must be finite numbers")
        if not b.contains(x, y):
            raise BadInputError(
                f"{where}: outside the world of {scenario.name} (x {b.x[0]:g}..{b.x[1]:g}, y {b.y[0]:g}..{b.y[1]:g})"
            )
        if math.hypot(x - start[0], y - start[1]) < clearance:
            raise BadInputError(f"{where}: on the robot's start pose ({start[0]:g}, {start[1]:g})")


def resolve_scenario_path(name_or_path: str | Path) -> Path:
    """A bundled scenario name, or a path to a YAML file."""
    text = str(name_or_path)
    if re.fullmatch(r"[A-Za-z0-9_-]+", text) and (scenario_dir() / f"{text}.yaml").exists():
        return scenario_dir() / f"{text}.yaml"
    path = Path(text)
    if path.is_file():
        return path
    known = ", ".join(list_scenarios())
    raise ScenarioError(f"{text}: no such scenario file or bundled scenario (bundled: {known})")


# libyaml's parser when PyYAML was built with it: the same documents, ~8x faster (the factory file
# parsed in 66 ms with the pure-Python one, a tenth of a drive's start).
_SAFE_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


@lru_cache(maxsize=32)
def _load_cached(path: str, mtime: float) -> Scenario:
    try:
        data = yaml.load(Path(path).read_text(encoding="utf-8"), Loader=_SAFE_LOADER)
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f"line {mark.line + 1}" if mark is not None else "(file)"
        problem = getattr(err, "problem", None) or "invalid YAML"
        raise ScenarioError(f"{path}: {where}: {problem}") from None
    except (OSError, UnicodeDecodeError) as err:
        raise ScenarioError(f"{path}: cannot read: {err}") from None
    return parse_scenario(data, path)


def load_scenario(name_or_path: str | Path) -> Scenario:
    """Load and validate a scenario by bundled name or path (cached by path and mtime)."""
    path = resolve_scenario_path(name_or_path)
    return _load_cached(str(path), path.stat().st_mtime)
