"""`scenarios check`: what a scenario file promises a robot, tested on its geometry.

For every task and start pose:

- clearance: the robot's footprint keeps its radius + `GridConfig.margin_m` from every solid shape below
  the robot's height and from the bounds (the free space of the true inflated grid);
- reachability: one of the task's approach cells (the oracle's: 1.5-2.5 m from a target's goal point,
  shrunk by its slack; a point target's own cell when free) lies in the same 8-connected free region of the
  inflated grid as the start cell — exactly when the oracle's A* finds a path;
- not already there: every target's goal point lies farther than the scorer's success radius (the oracle's
  `approach_max_m`, 2.5 m) plus `START_SLACK_M` from the start, walls or no walls;
- not visible: no target is in line of sight within the camera's view at the start pose (its horizontal
  field of view plus `FOV_MARGIN_DEG` each side; `sightlines`), and the start is not on a target's own
  footprint (a room's floor). The generator asks more of its own start poses: no target in sight in any
  direction.

Malformed or hostile files (bad YAML, YAML aliases or deep nesting, wrong fields, NaN, a world too large to
rasterise) give one line per problem and no traceback; the geometric tests run only on a file that loads.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import yaml
from pydantic import ValidationError
from scipy import ndimage

from llmnav.buildings.sightlines import blockers, visible
from llmnav.core.robot_specs import ROBOT_SPECS
from llmnav.core.safefiles import read_text
from llmnav.errors import BadInputError
from llmnav.mapping.grid import GridConfig, GridGeometry, build_grid
from llmnav.mapping.targets import OracleConfig
from llmnav.world.scenario import Scenario, consistency_problems

if TYPE_CHECKING:
    from llmnav.mapping.grid import OccupancyGrid
    from llmnav.world.scenario import LabelledObject, Shape, Task

MAX_FILE_BYTES = 4 << 20  # [bytes] a generated office is ~40 kB
MAX_DEPTH = 32  # YAML nesting; a scenario nests about 6 deep
MAX_CELLS = 4_000_000  # grid cells (0.05 m): 10 000 m², e.g. 100 m x 100 m
MAX_SHAPES = 5_000  # walls, obstacles and objects together
MAX_STARTS = 2_000  # start poses over all tasks
MAX_LINES = 100  # problems listed before the rest are counted
START_SLACK_M = 0.5  # [m] beyond the success radius: a task must not begin solved
FOV_MARGIN_DEG = 7.5  # [deg] beyond the camera's half field of view (the factory's +-45 deg for +-37.6)


def _yaml_problems(text: str, source: str) -> list[str]:
    """Aliases and over-deep nesting, found on the event stream before anything is built from it."""
    loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
    depth = 0
    try:
        for event in yaml.parse(text, Loader=loader):
            line = f"line {event.start_mark.line + 1}" if event.start_mark is not None else "(file)"
            if isinstance(event, yaml.AliasEvent):
                return [f"{source}: {line}: YAML aliases (*name) are not allowed here"]
            if isinstance(event, yaml.CollectionStartEvent):
                depth += 1
                if depth > MAX_DEPTH:
                    return [f"{source}: {line}: nested deeper than {MAX_DEPTH} levels"]
            elif isinstance(event, yaml.CollectionEndEvent):
                depth -= 1
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f"line {mark.line + 1}" if mark is not None else "(file)"
        if isinstance(err, yaml.reader.ReaderError):  # a control character or undecodable byte
            where = f"character {err.position + 1}"
        problem = getattr(err, "problem", None) or getattr(err, "reason", None) or "invalid YAML"
        return [f"{source}: {where}: {problem}"]
    return []


def _loc(loc: tuple[int | str, ...]) -> str:
    out = ""
    for part in loc:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out or "(top level)"


def load_for_check(path: Path) -> tuple[Scenario | None, list[str]]:
    """The scenario in `path`, or None and one line per problem that kept it from loading."""
    source = str(path)
    try:
        text = read_text(path, limit=MAX_FILE_BYTES, what=source)
    except FileNotFoundError:
        return None, [f"{source}: no such file"]
    except BadInputError as err:
        return None, [str(err)]
    except OSError as err:  # a folder opens, then cannot be read
        return None, [f"{source}: cannot read: {err.strerror or err}"]
    problems = _yaml_problems(text, source)
    if problems:
        return None, problems
    data = yaml.load(text, Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))
    if not isinstance(data, dict):
        return None, [f"{source}: (top level): expected a mapping, got {type(data).__name__}"]
    try:
        scenario = Scenario.model_validate(data)
    except ValidationError as err:
        return None, [
            f"{source}: {_loc(tuple(e['loc']))}: {e['msg'].removeprefix('Value error, ')}" for e in err.errors()
        ]
    problems = [f"{source}: {where}: {what}" for where, what in consistency_problems(scenario)]
    return scenario, problems


def _size_problems(scenario: Scenario, source: str) -> list[str]:
    """What makes a valid scenario too large to check."""
    geometry = GridGeometry.from_bounds(scenario.bounds, GridConfig().resolution_m)
    problems = []
    if geometry.rows * geometry.cols > MAX_CELLS:
        width, depth = scenario.bounds.x[1] - scenario.bounds.x[0], scenario.bounds.y[1] - scenario.bounds.y[0]
        problems.append(
            f"{source}: bounds: a {width:g} m x {depth:g} m world is over the {MAX_CELLS} grid cells "
            f"({GridConfig().resolution_m:g} m) check rasterises"
        )
    shapes = len(scenario.walls) + len(scenario.obstacles) + len(scenario.objects)
    if shapes > MAX_SHAPES:
        problems.append(f"{source}: {shapes} walls, obstacles and objects, over the {MAX_SHAPES} check takes")
    starts = sum(len(t.start_poses) for t in scenario.tasks)
    if starts > MAX_STARTS:
        problems.append(f"{source}: {starts} start poses, over the {MAX_STARTS} check takes")
    return problems


def _approach_mask(grid: OccupancyGrid, point: tuple[float, float], exact: bool, config: OracleConfig) -> np.ndarray:
    """The oracle's stopping cells for one target (see `mapping.targets`)."""
    geometry = grid.geometry
    if exact and grid.is_free(*point):
        mask = np.zeros(geometry.shape, dtype=bool)
        mask[geometry.world_to_cell(*point)] = True
        return mask
    xs, ys = geometry.centres()
    distance = np.hypot(xs - point[0], ys - point[1])
    low, high = config.approach_min_m + config.band_slack_m, config.approach_max_m - config.band_slack_m
    return np.asarray((distance >= low) & (distance <= high) & ~grid.blocked)


class Judge:
    """The three tests of one scenario, with its grid and free regions computed once.

    The generator asks it about candidate start poses; `check_scenario` about the poses in a file.
    """

    def __init__(self, scenario: Scenario) -> None:
        self.scenario = scenario
        self.robot = ROBOT_SPECS[scenario.robot]
        self.grid = build_grid(scenario)
        self.clear_m = self.grid.inflation_m  # [m] radius + grid margin
        self.labels, _ = ndimage.label(~self.grid.blocked, structure=np.ones((3, 3), dtype=int))
        self._solids = [s for s in scenario.solid_shapes() if s.z < self.robot.height_m]

    def clearance(self, x: float, y: float) -> float:
        """Distance [m] from (x, y) to the nearest solid shape below the robot's height or the bounds."""
        b = self.scenario.bounds
        edge = min(x - b.x[0], b.x[1] - x, y - b.y[0], b.y[1] - y)
        return min([edge, *(s.distance_to(x, y) for s in self._solids)])

    def target_regions(self, task: Task) -> set[int]:
        """The free regions holding an approach cell of any of the task's targets."""
        config = OracleConfig()
        found: set[int] = set()
        for target in task.targets:
            if target.object is not None:
                obj = self.scenario.object(target.object)
                point, exact = obj.goal_point, bool(self.scenario.corridors) and obj.goal is not None
            else:
                assert target.point is not None
                point, exact = target.point, True
            mask = _approach_mask(self.grid, (float(point[0]), float(point[1])), exact, config)
            found |= {int(v) for v in np.unique(self.labels[mask]) if v}
        return found

    def region(self, x: float, y: float) -> int:
        """The free region of (x, y)'s cell (0: blocked or outside the grid)."""
        cell = self.grid.geometry.world_to_cell(x, y)
        return int(self.labels[cell]) if self.grid.geometry.contains(cell) else 0

    def blockers_for(self, target_ids: set[str]) -> list[Shape]:
        """What hides the targets named (they never hide themselves)."""
        return blockers(self.scenario, self.robot.camera_height_m, target_ids)

    @property
    def half_fov(self) -> float:
        """Half the camera's horizontal field of view plus the margin [rad]."""
        camera = self.scenario.sensors.camera
        half_vertical = math.radians(camera.fov_deg) / 2
        return math.atan(math.tan(half_vertical) * camera.width / camera.height) + math.radians(FOV_MARGIN_DEG)

    def sight_problem(
        self, x: float, y: float, targets: list[LabelledObject], blocking: list[Shape], yaw: float | None = None
    ) -> str | None:
        """Why a start at (x, y) is too near or sees its target, or None (seen in view of `yaw` [rad], or anywhere)."""
        near_m = OracleConfig().approach_max_m + START_SLACK_M
        for obj in targets:
            gx, gy = obj.goal_point
            away_m = math.hypot(gx - x, gy - y)
            if away_m <= near_m:
                within = f"{near_m - START_SLACK_M:g} m + {START_SLACK_M:g} m"
                return f"target '{obj.id}' is {away_m:.2f} m away: the task begins within {within}"
            if not obj.solid and obj.contains(x, y):
                return f"starts on its target '{obj.id}'"
            if yaw is None and visible((x, y), obj, blocking):
                return f"target '{obj.id}' is in line of sight"
            if yaw is not None and visible((x, y), obj, blocking, yaw, self.half_fov):
                return f"target '{obj.id}' is in the camera's view"
        return None


def check_scenario(scenario: Scenario, source: str) -> list[str]:
    """One line per broken promise of a loaded scenario (see the module docstring); [] when all hold."""
    problems = _size_problems(scenario, source)
    if problems:
        return problems
    judge = Judge(scenario)
    for ti, task in enumerate(scenario.tasks):
        ids = {t.object for t in task.targets if t.object is not None}
        targets = [scenario.object(i) for i in sorted(ids)]
        blocking = judge.blockers_for(ids)
        regions = judge.target_regions(task) if task.targets else set()
        for si, start in enumerate(task.start_poses):
            where = f"{source}: tasks[{ti}].start_poses[{si}] ({task.id} start {si + 1} at {start.x:g}, {start.y:g})"
            nearest = judge.clearance(start.x, start.y)
            if not math.isfinite(nearest) or nearest < judge.clear_m:
                problems.append(
                    f"{where}: {max(nearest, 0.0):.2f} m from the nearest wall or object; the {scenario.robot} "
                    f"needs {judge.clear_m:.2f} m"
                )
                continue
            if not task.targets:
                continue
            if judge.region(start.x, start.y) not in regions:
                problems.append(
                    f"{where}: no target can be reached by the {scenario.robot} (radius {judge.robot.radius_m:g} m)"
                )
            sight = judge.sight_problem(start.x, start.y, targets, blocking, math.radians(start.yaw_deg))
            if sight is not None:
                problems.append(f"{where}: {sight}")
    return problems


def check_file(path: Path) -> list[str]:
    """Every problem of the scenario file at `path`, one line each, at most `MAX_LINES` (then a count)."""
    scenario, problems = load_for_check(path)
    if scenario is not None and not problems:
        problems = check_scenario(scenario, str(path))
    if len(problems) > MAX_LINES:
        problems = [*problems[:MAX_LINES], f"{path}: {len(problems) - MAX_LINES} more problems not listed"]
    return problems
