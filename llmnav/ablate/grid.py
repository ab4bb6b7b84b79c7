"""Ablation grids: the spec (flags or YAML), parsing, and its expansion into episodes with keys and seeds."""

from __future__ import annotations

import hashlib
import itertools
import json
import math
import re
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from llmnav.errors import BadInputError, redact_userinfo, validation_message
from llmnav.planners.base import (
    DEFAULT_PLANNER,
    DriveOptions,
    check_option_value,
    drive_options,
    option_names,
    option_value,
    planner_class,
    planner_taking,
    usable_planner_names,
)

if TYPE_CHECKING:
    from llmnav.runs.runner import EpisodeSpec

# Factors of every grid; any planner option may be a factor too (see `GridSpec`).
CORE_FACTORS: tuple[str, ...] = ("planner", "backend")
LAST_FACTORS: tuple[str, ...] = ("wording",)
DEFAULT_BACKEND = "local"
_SEED_SPACE = 2**31 - 1  # seeds stay positive 32-bit ints (PyBullet, numpy, model servers)


def _factor_values(values: list[Any] | None) -> list[Any] | None:
    if values is not None and not values:
        raise ValueError("a factor needs at least one value")
    if values is not None and len(set(map(str, values))) != len(values):
        raise ValueError("a factor lists the same value twice")
    return values


def factor_order() -> list[str]:
    """Option factors in a stable order: each registered planner's declared `grid_factors`, by name."""
    order: list[str] = []
    for name in usable_planner_names():
        order += [f for f in planner_class(name).grid_factors if f not in order]
    return order


class GridSpec(BaseModel):
    """An ablation grid, from CLI flags or a YAML file with the same keys."""

    name: str | None = None
    scenario: str = "factory"
    tasks: list[str] | Literal["all"] = "all"
    poses: list[int] | None = None  # 1-based start-pose indices; None = every start pose of each task
    trials: int = Field(default=1, ge=1)
    seed: int = 0
    # ablated factors (None = not ablated: the default of the planner's options, or `backend` below)
    planner: list[str] | None = None
    backend: list[str] | None = None
    wording: list[str] | None = None  # "bundled", "paraphrase:<k>" (llmnav.world.tasks.worded_text)
    options: dict[str, Any] = {}  # fixed planner options for every episode (max_iterations, image size, ...)
    # Any other key is an option factor: a planner option and its values, e.g. `lidar_sectors: [3, 8]`.
    model_config = ConfigDict(extra="allow")

    @field_validator("name")
    @classmethod
    def _plain_name(cls, name: str | None) -> str | None:
        # the name becomes a folder under ablations/: a path (/etc, ../x) would put the sweep elsewhere
        if name is not None and (not name.strip() or name != Path(name).name or name in (".", "..")):
            raise ValueError(f"{name!r} is not a plain folder name (use --out for a path)")
        return name

    @field_validator("poses")
    @classmethod
    def _positive(cls, poses: list[int] | None) -> list[int] | None:
        if poses is not None and (not poses or min(poses) < 1):
            raise ValueError("start poses are 1-based and at least one is needed")
        return poses

    @field_validator("wording", mode="before")
    @classmethod
    def _canonical_wording(cls, values: Any) -> Any:
        # `paraphrase:01` is `paraphrase:1`: written both ways it would run one wording twice, same seeds
        if not isinstance(values, list):
            return values
        out = []
        for value in values:
            prefix, sep, number = str(value).strip().partition(":")
            out.append(f"{prefix}:{int(number)}" if sep and number.strip().isdigit() else value)
        return out

    @field_validator("planner", "backend", "wording")
    @classmethod
    def _non_empty(cls, values: list[Any] | None) -> list[Any] | None:
        return _factor_values(values)

    @model_validator(mode="after")
    def _option_factors(self) -> GridSpec:
        # each extra key must be an option of some planner (one the grid's planners ignore gets a note)
        for name, values in (self.model_extra or {}).items():
            if planner_taking(name) is None:
                planners = self.planners()
                known = ", ".join(sorted({k for p in planners for k in option_names(p)}))
                raise ValueError(f"'{name}' is no option of any planner (options of {', '.join(planners)}: {known})")
            setattr(self, name, _factor_values(values if isinstance(values, list) else [values]))
        return self

    def planners(self) -> list[str]:
        """The grid's planners (the default planner when `planner` is not a factor)."""
        return list(self.planner or [DEFAULT_PLANNER])

    def option_factors(self) -> dict[str, list[Any]]:
        """The planner options varied (the extra keys), in `factor_order`."""
        extra = {k: v for k, v in (self.model_extra or {}).items() if v is not None}
        order = factor_order()
        return {k: list(extra[k]) for k in sorted(extra, key=lambda k: order.index(k) if k in order else len(order))}

    def factors(self) -> dict[str, list[Any]]:
        """The ablated factors and their values: planner, backend, the option factors, wording."""
        core = {name: list(getattr(self, name)) for name in CORE_FACTORS if getattr(self, name) is not None}
        last = {name: list(getattr(self, name)) for name in LAST_FACTORS if getattr(self, name) is not None}
        return {**core, **self.option_factors(), **last}

    def default_name(self) -> str:
        """`<scenario>-<factor>-<factor>` (or `<scenario>-base`)."""
        return self.name or "-".join([Path(self.scenario).stem, *self.factors()] or ["base"])


@dataclass(frozen=True)
class Episode:
    """One episode of a grid: what to run and where."""

    key: str
    dir_name: str
    task_id: str
    start_pose: int
    trial: int
    seed: int
    factors: dict[str, Any]
    backend: str
    options: DriveOptions
    # The episode's full condition (see `condition`) and its hash: a run folder is this episode's result
    # only when its config line carries the same hash.
    condition: dict[str, Any] = field(default_factory=dict, compare=False)
    identity: str = ""

    def spec(self, root: Path, scenario: str, *, plots: bool = False, dir_name: str | None = None) -> EpisodeSpec:
        """The runner's input for this episode.

        `plots`: write each run's trajectory.png; `dir_name`: the folder under `root` when not the
        episode's first choice.
        """
        from llmnav.runs.runner import EpisodeSpec
        from llmnav.world.tasks import worded_text

        text = worded_text(scenario, self.task_id, str(self.factors.get("wording", "bundled")))
        return EpisodeSpec(
            scenario=scenario,
            task_id=None if text else self.task_id,
            task_text=text,
            start_pose=self.start_pose,
            options=self.options,
            backend=self.backend,
            out_dir=root / (dir_name or self.dir_name),
            quiet=True,
            plots=plots,
            condition=self.identity or None,
        )


# --- parsing flags and files --------------------------------------------------------------------


def split_list(text: str) -> list[str]:
    """`3,5,8` → ["3", "5", "8"] (spaces ignored)."""
    return [part.strip() for part in text.split(",") if part.strip()]


def parse_poses(text: str) -> list[int] | None:
    """`1-5`, `1,3,4`, `2` or `all` (None)."""
    if text.strip().lower() == "all":
        return None
    poses: list[int] = []
    for part in split_list(text):
        low, sep, high = part.partition("-")
        try:
            values = range(int(low), int(high) + 1) if sep else [int(low)]
        except ValueError:
            raise BadInputError(f"--poses {text!r}: expected e.g. 1-5 or 1,3,4") from None
        poses.extend(v for v in values if v not in poses)
    if not poses:
        raise BadInputError(f"--poses {text!r}: no start pose selected")
    return poses


_validation_message = validation_message


def grid_from_mapping(data: dict[str, Any], source: str) -> GridSpec:
    """Validate grid data (from a file and/or flags); one-line BadInputError naming the source."""
    try:
        grid = GridSpec.model_validate(data)
        for planner in grid.planners():  # the fixed options one planner takes
            episode_options(planner, grid.options, {}, grid.seed)
        _check_fixed_options(grid)
    except ValidationError as err:
        raise BadInputError(f"{source}: {_validation_message(err)}") from None
    return grid


def _check_fixed_options(grid: GridSpec) -> None:
    """A fixed option no planner takes is a typo: refused, naming what the grid's planners take."""
    planners = grid.planners()
    known = {k for p in planners for k in option_names(p)}
    unknown = sorted(k for k in grid.options if planner_taking(k) is None)
    if unknown:
        raise BadInputError(
            f"options {', '.join(unknown)}: no option of planner {', '.join(planners)} "
            f"(options: {', '.join(sorted(known))})"
        )


def _refuse_repeats(what: str, given: list[Any], meant: list[Any]) -> None:
    """Refuse a task or a factor value given twice, however written (`T6,t6`; `0.3,0.30`; `8,08,8.0`).

    `meant` is what each given value means (a task's id, an option's validated value). Run twice, one
    condition would get two episodes with the same key and seeds (two workers once collided on one folder).
    """
    seen: dict[str, Any] = {}
    for value, canonical in zip(given, meant, strict=True):
        if canonical in seen:
            raise BadInputError(f"{what}: {seen[canonical]!s} and {value!s} are the same value; give it once")
        seen[canonical] = value


class _UniqueKeyLoader(yaml.SafeLoader):
    """YAML's safe loader, refusing a key given twice in one mapping (YAML would keep the last silently)."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        seen: set[Any] = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)
            if isinstance(key, (str, int, float, bool)) and key in seen:
                raise yaml.constructor.ConstructorError(None, None, f"key {key!r} is given twice", key_node.start_mark)
            seen.add(key)
        return super().construct_mapping(node, deep=deep)


def load_grid_file(path: Path) -> dict[str, Any]:
    """The raw mapping of a grid YAML file (validated later, merged with flags)."""
    from llmnav.core.safefiles import SUMMARY_LIMIT, read_bytes

    try:
        raw = read_bytes(Path(path).resolve(), limit=SUMMARY_LIMIT, what=f"--grid {path}")  # no FIFO, no /dev/zero
        data = yaml.load(raw.decode("utf-8"), _UniqueKeyLoader)  # a SafeLoader
    except FileNotFoundError:
        raise BadInputError(f"--grid {path}: no such file") from None
    except OSError as err:
        raise BadInputError(f"--grid {path}: cannot read: {err.strerror or err}") from None
    except UnicodeDecodeError:
        raise BadInputError(f"--grid {path}: not a text file (not UTF-8); give a YAML grid file") from None
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f"line {mark.line + 1}" if mark is not None else "(file)"
        raise BadInputError(f"--grid {path}: {where}: {getattr(err, 'problem', None) or 'invalid YAML'}") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise BadInputError(f"--grid {path}: expected a mapping of grid keys")
    if isinstance(data.get("poses"), (str, int)):
        data["poses"] = parse_poses(str(data["poses"]))
    if isinstance(data.get("tasks"), str) and data["tasks"].lower() != "all":
        data["tasks"] = split_list(data["tasks"])
    for name in set(data) - _SCALAR_KEYS:  # a scalar factor is a one-value list
        if data[name] is not None and not isinstance(data[name], list):
            data[name] = [data[name]]
    return data


# --- expanding a grid ---------------------------------------------------------------------------


def _safe(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.+=-]+", "-", text).strip("-") or "x"


def episode_seed(base_seed: int, task_id: str, start_pose: int, trial: int) -> int:
    """A seed from (base seed, task, pose, trial): the same for every condition, independent of order."""
    digest = hashlib.sha256(f"{base_seed}|{task_id}|{start_pose}|{trial}".encode()).digest()
    return int.from_bytes(digest[:8], "big") % _SEED_SPACE


def episode_key(task_id: str, start_pose: int, trial: int, factors: dict[str, Any]) -> str:
    """`T8-p1-t2` plus `-lidar_sectors=3` per factor given (callers pass the ones that vary)."""
    parts = [f"{task_id}-p{start_pose}-t{trial}"]
    # a key names a folder and a manifest entry: a backend URL's credentials stay out of both
    parts += [f"{name}={redact_userinfo(str(value))}" for name, value in factors.items()]
    return "-".join(parts)


_SCALAR_KEYS = frozenset({"name", "scenario", "tasks", "poses", "trials", "seed", "options"})


def _dir_name(key: str) -> str:
    name = _safe(key)
    if len(name) > 100 or name != key:  # long or rewritten: keep it unique with a short hash
        name = f"{name[:90]}-{hashlib.sha256(key.encode()).hexdigest()[:8]}"
    return name


def episode_options(planner: str, fixed: dict[str, Any], factors: dict[str, Any], seed: int) -> DriveOptions:
    """One episode's options: the fixed options and factor values that `planner` takes (the rest it ignores)."""
    model = planner_class(planner).Options
    given = {**fixed, **{k: v for k, v in factors.items() if k not in ("backend", "wording", "planner")}}
    taken = {k: option_value(model, k, v) for k, v in given.items() if k in model.input_keys()}
    return drive_options(planner, **{**taken, "seed": seed})


def condition(
    scenario_hash: str,
    task_id: str,
    start_pose: int,
    trial: int,
    backend: str,
    options: DriveOptions,
    wording: str = "bundled",
) -> dict[str, Any]:
    """Everything that decides an episode's result.

    Scenario file content, task and its wording, start pose, trial, backend spec (model and URL; secrets
    redacted), every option (seed included) and the prompt templates used.
    """
    from llmnav.backends.http import redact

    return {
        "scenario_sha256": scenario_hash,
        "task": task_id,
        "wording": wording,
        "start_pose": start_pose,
        "trial": trial,
        "backend": redact(backend.strip()),
        "options": options.model_dump(mode="json"),
        "prompt_hashes": _prompt_hashes(options),
    }


def condition_hash(data: dict[str, Any]) -> str:
    """A stable hash of a condition (canonical JSON)."""
    return hashlib.sha256(json.dumps(data, sort_keys=True, default=str).encode()).hexdigest()


def _prompt_hashes(options: DriveOptions) -> dict[str, str]:
    return dict(_prompt_hashes_cached(options.model_dump_json()))


@lru_cache(maxsize=256)
def _prompt_hashes_cached(options_json: str) -> tuple[tuple[str, str], ...]:
    from llmnav.planners.base import get_planner
    from llmnav.runs.runner import prompt_hashes

    options = drive_options(**json.loads(options_json))
    return tuple(sorted(prompt_hashes(get_planner(options.planner), options).items()))


def check_backend(spec: str) -> None:
    """Refuse a backend spec naming no installed backend (what the real run would refuse, before any work)."""
    from llmnav.backends.base import backend_class

    cls, arg = backend_class(spec)  # unknown, clashing or broken: a one-line BackendSpecError
    cls.check_arg(arg)  # and an argument no run could use (`openai:m@http://`)


MAX_EPISODES = 20_000  # a grid larger than this is a typo more often than a plan (`--max-episodes` raises it)


def check_size(grid: GridSpec, pose_counts: dict[str, int], max_episodes: int) -> int:
    """The number of episodes, from the factor lengths alone; BadInputError above `max_episodes`.

    Computed before anything is built: `trials: 1000000000` must be refused, not expanded into memory.
    """
    per_pose = grid.trials * math.prod(len(values) for values in grid.factors().values())
    size = per_pose * sum(pose_counts.values())
    if size > max_episodes:
        detail = ", ".join(f"{k}: {len(v)}" for k, v in grid.factors().items()) or "no factors"
        raise BadInputError(
            f"the grid has {size:,} episodes ({len(pose_counts)} task(s), {sum(pose_counts.values())} start "
            f"pose(s), trials: {grid.trials}, {detail}), over the limit of {max_episodes:,}; "
            "use --max-episodes to allow more"
        )
    return size


def expand(grid: GridSpec, max_episodes: int = MAX_EPISODES) -> list[Episode]:
    """Every episode of the grid, in a stable order (task, pose, trial, then factors).

    BadInputError before anything is built when the grid holds more than `max_episodes`.
    """
    from llmnav.world.scenario import load_scenario, resolve_scenario_path
    from llmnav.world.tasks import worded_text

    scenario = load_scenario(grid.scenario)
    scenario_hash = hashlib.sha256(resolve_scenario_path(grid.scenario).read_bytes()).hexdigest()
    if grid.tasks == "all":
        tasks = [t.id for t in scenario.tasks]
    else:
        tasks = []
        for name in grid.tasks:
            try:
                tasks.append(scenario.task(name).id)
            except KeyError:
                known = ", ".join(t.id for t in scenario.tasks)
                raise BadInputError(
                    f"--tasks: scenario {scenario.name} has no task '{name}' (tasks: {known})"
                ) from None
    if not tasks:
        raise BadInputError(f"scenario {scenario.name} has no tasks to ablate")
    _refuse_repeats("--tasks", list(grid.tasks) if grid.tasks != "all" else tasks, tasks)
    pose_counts: dict[str, int] = {}
    for task_id in tasks:
        available = len(scenario.start_poses(scenario.task(task_id)))
        poses = grid.poses or list(range(1, available + 1))
        if max(poses) > available:
            raise BadInputError(f"--poses: task {task_id} has {available} start pose(s), asked for {max(poses)}")
        pose_counts[task_id] = len(poses)
    check_size(grid, pose_counts, max_episodes)
    for key, values in grid.option_factors().items():  # every value, also where a planner ignores it
        try:
            meant = [repr(check_option_value(key, value, grid.planners()[0])) for value in values]
        except ValidationError as err:
            raise BadInputError(f"grid value: {_validation_message(err)}") from None
        _refuse_repeats(key, values, meant)
    for backend_spec in dict.fromkeys(grid.backend or [DEFAULT_BACKEND]):
        check_backend(backend_spec)
    factors = grid.factors()
    names = list(factors)
    combos = [dict(zip(names, values, strict=True)) for values in itertools.product(*factors.values())]
    # Keys name only the factors that vary; one-value factors are checked against the logged options.
    varying = {name for name, values in factors.items() if len(values) > 1}
    episodes: list[Episode] = []
    for task_id in tasks:
        available = len(scenario.start_poses(scenario.task(task_id)))
        poses = grid.poses or list(range(1, available + 1))
        for wording in factors.get("wording", []):
            worded_text(grid.scenario, task_id, str(wording))  # a task without this wording is bad input
        for pose, trial, combo in itertools.product(poses, range(1, grid.trials + 1), combos):
            seed = episode_seed(grid.seed, task_id, pose, trial)
            try:
                options = episode_options(str(combo.get("planner", grid.planners()[0])), grid.options, combo, seed)
            except ValidationError as err:
                raise BadInputError(f"grid value: {_validation_message(err)}") from None
            key = episode_key(task_id, pose, trial, {k: v for k, v in combo.items() if k in varying})
            backend = str(combo.get("backend", (grid.backend or [DEFAULT_BACKEND])[0]))
            wording = str(combo.get("wording", "bundled"))
            cond = condition(scenario_hash, task_id, pose, trial, backend, options, wording)
            episodes.append(
                Episode(
                    key,
                    _dir_name(key),
                    task_id,
                    pose,
                    trial,
                    seed,
                    combo,
                    backend,
                    options,
                    cond,
                    condition_hash(cond),
                )
            )
    return episodes
