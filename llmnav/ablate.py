"""Ablation sweeps: a grid of conditions → episodes, run resumably and in parallel, with a manifest.

A grid is the cartesian product of the ablated factors (`lidar_sectors`, `prompt`, `history`, `sensing`,
`backend`, `assist`, `planner`) over tasks × start poses × trials. Each episode has a key naming it
(`T8-p1-t2-lidar_sectors=3`: task, start pose, trial and the factors with several values), one run
folder under the ablation folder named from that key, and a seed derived from (base seed, task, pose,
trial): every condition sees the same seeds, so differences between conditions come from the factor, not
from the noise, and results never depend on the order or the process that ran an episode.

`manifest.json` (rewritten atomically after every episode) lists every episode with its key, folder,
seed, factors, status and summary. Running the same grid again skips episodes whose `summary.json` is
present and consistent with the episode, and deletes and reruns the others (cut short by a kill, crashed).
Episodes run through `llmnav.runner.run_episode` — in this process, in a spawn process pool, or as Ray
tasks; the parent alone writes the manifest.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import os
import re
import shutil
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from llmnav.errors import BadInputError, one_line
from llmnav.planners.base import DriveOptions
from llmnav.runlog import RUN_FILE, SUMMARY_FILE, write_json_atomic

if TYPE_CHECKING:
    from llmnav.runner import EpisodeSpec

MANIFEST_FILE = "manifest.json"
# The factors an ablation may vary, in the order they appear in keys and tables.
FACTORS: tuple[str, ...] = ("planner", "backend", "sensing", "lidar_sectors", "prompt", "history", "assist")
DEFAULT_BACKEND = "local"
_SEED_SPACE = 2**31 - 1  # seeds stay positive 32-bit ints (PyBullet, numpy, model servers)

Runner = Callable[["EpisodeSpec"], dict[str, Any]]
Status = Literal["pending", "done", "error"]


class GridSpec(BaseModel):
    """An ablation grid, from CLI flags or a YAML file with the same keys."""

    model_config = ConfigDict(extra="forbid")

    name: str | None = None
    scenario: str = "factory"
    tasks: list[str] | Literal["all"] = "all"
    poses: list[int] | None = None  # 1-based start-pose indices; None = every start pose of each task
    trials: int = Field(default=1, ge=1)
    seed: int = 0
    # ablated factors (None = not ablated: the default of DriveOptions, or `backend` below)
    planner: list[str] | None = None
    backend: list[str] | None = None
    sensing: list[str] | None = None  # each "lidar+image", "image", ...
    lidar_sectors: list[int] | None = None
    prompt: list[str] | None = None
    history: list[str] | None = None
    assist: list[str] | None = None
    options: dict[str, Any] = {}  # fixed DriveOptions for every episode (max_iterations, image size, ...)

    @field_validator("poses")
    @classmethod
    def _positive(cls, poses: list[int] | None) -> list[int] | None:
        if poses is not None and (not poses or min(poses) < 1):
            raise ValueError("start poses are 1-based and at least one is needed")
        return poses

    @field_validator("planner", "backend", "sensing", "lidar_sectors", "prompt", "history", "assist")
    @classmethod
    def _non_empty(cls, values: list[Any] | None) -> list[Any] | None:
        if values is not None and not values:
            raise ValueError("a factor needs at least one value")
        if values is not None and len(set(map(str, values))) != len(values):
            raise ValueError("a factor lists the same value twice")
        return values

    def factors(self) -> dict[str, list[Any]]:
        """The ablated factors and their values, in FACTORS order."""
        return {name: list(getattr(self, name)) for name in FACTORS if getattr(self, name) is not None}

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

    def spec(self, root: Path, scenario: str, *, plots: bool = False) -> EpisodeSpec:
        """The runner's input for this episode (`plots`: write each run's trajectory.png)."""
        from llmnav.runner import EpisodeSpec

        return EpisodeSpec(
            scenario=scenario,
            task_id=self.task_id,
            start_pose=self.start_pose,
            options=self.options,
            backend=self.backend,
            out_dir=root / self.dir_name,
            quiet=True,
            plots=plots,
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


def _validation_message(err: ValidationError) -> str:
    first = err.errors()[0]
    where = ".".join(str(p) for p in first["loc"]) or "(top level)"
    return f"{where}: {first['msg'].removeprefix('Value error, ')}"


def grid_from_mapping(data: dict[str, Any], source: str) -> GridSpec:
    """Validate grid data (from a file and/or flags); one-line BadInputError naming the source."""
    try:
        grid = GridSpec.model_validate(data)
        DriveOptions.model_validate(grid.options)
    except ValidationError as err:
        raise BadInputError(f"{source}: {_validation_message(err)}") from None
    return grid


def load_grid_file(path: Path) -> dict[str, Any]:
    """The raw mapping of a grid YAML file (validated later, merged with flags)."""
    try:
        data = yaml.safe_load(Path(path).read_text(encoding="utf-8"))
    except OSError as err:
        raise BadInputError(f"--grid {path}: cannot read: {err.strerror or err}") from None
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f"line {mark.line + 1}" if mark is not None else "(file)"
        raise BadInputError(
            f"--grid {path}: {where}: {getattr(err, 'problem', None) or 'invalid YAML'}"
        ) from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise BadInputError(f"--grid {path}: expected a mapping of grid keys")
    if isinstance(data.get("poses"), (str, int)):
        data["poses"] = parse_poses(str(data["poses"]))
    if isinstance(data.get("tasks"), str) and data["tasks"].lower() != "all":
        data["tasks"] = split_list(data["tasks"])
    for name in FACTORS:  # a scalar factor is a one-value list
        if name in data and data[name] is not None and not isinstance(data[name], list):
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
    parts += [f"{name}={value}" for name, value in factors.items()]
    return "-".join(parts)


def _dir_name(key: str) -> str:
    name = _safe(key)
    if len(name) > 100 or name != key:  # long or rewritten: keep it unique with a short hash
        name = f"{name[:90]}-{hashlib.sha256(key.encode()).hexdigest()[:8]}"
    return name


def _factor_options(factors: dict[str, Any]) -> dict[str, Any]:
    """DriveOptions fields set by the factors (backend is not an option)."""
    options: dict[str, Any] = {}
    for name, value in factors.items():
        if name == "backend":
            continue
        if name == "sensing":
            options["sensing"] = tuple(part for part in str(value).split("+") if part)
        elif name == "history":
            options["history"] = str(value)
        else:
            options[name] = value
    return options


def expand(grid: GridSpec) -> list[Episode]:
    """Every episode of the grid, in a stable order (task, pose, trial, then factors)."""
    from llmnav.scenario import load_scenario

    scenario = load_scenario(grid.scenario)
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
    factors = grid.factors()
    names = list(factors)
    combos = [dict(zip(names, values, strict=True)) for values in itertools.product(*factors.values())]
    # Keys name only the factors that vary; one-value factors are checked against the logged options.
    varying = {name for name, values in factors.items() if len(values) > 1}
    episodes: list[Episode] = []
    for task_id in tasks:
        available = len(scenario.start_poses(scenario.task(task_id)))
        poses = grid.poses or list(range(1, available + 1))
        if max(poses) > available:
            raise BadInputError(
                f"--poses: task {task_id} has {available} start pose(s), asked for {max(poses)}"
            )
        for pose, trial, combo in itertools.product(poses, range(1, grid.trials + 1), combos):
            seed = episode_seed(grid.seed, task_id, pose, trial)
            try:
                options = DriveOptions.model_validate(
                    {**grid.options, **_factor_options(combo), "seed": seed}
                )
            except ValidationError as err:
                raise BadInputError(f"grid value: {_validation_message(err)}") from None
            key = episode_key(task_id, pose, trial, {k: v for k, v in combo.items() if k in varying})
            backend = str(combo.get("backend", (grid.backend or [DEFAULT_BACKEND])[0]))
            episodes.append(Episode(key, _dir_name(key), task_id, pose, trial, seed, combo, backend, options))
    return episodes


# --- the manifest -------------------------------------------------------------------------------


@dataclass
class ManifestEntry:
    """One episode's line in manifest.json."""

    key: str
    dir: str  # relative to the ablation folder
    task_id: str
    start_pose: int
    trial: int
    seed: int
    factors: dict[str, Any]
    status: Status = "pending"
    summary: str | None = None  # relative path of summary.json
    outcome: str | None = None
    success: bool | None = None
    score: float | None = None
    error: str | None = None

    def record(self, summary: dict[str, Any]) -> None:
        """Mark done with the episode's summary."""
        self.status, self.error = "done", None
        self.summary = f"{self.dir}/{SUMMARY_FILE}"
        self.outcome = summary.get("outcome")
        self.success = bool(summary.get("success"))
        self.score = summary.get("score")


@dataclass
class Ablation:
    """A grid expanded into episodes, bound to its folder."""

    grid: GridSpec
    root: Path
    episodes: list[Episode]
    entries: dict[str, ManifestEntry] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for ep in self.episodes:
            self.entries.setdefault(
                ep.key,
                ManifestEntry(
                    ep.key, ep.dir_name, ep.task_id, ep.start_pose, ep.trial, ep.seed, dict(ep.factors)
                ),
            )

    @property
    def size(self) -> int:
        """Number of episodes."""
        return len(self.episodes)

    def manifest(self) -> dict[str, Any]:
        """The manifest as data (no timestamps: an interrupted and resumed sweep gives the same one)."""
        entries = [self.entries[ep.key].__dict__ for ep in self.episodes]
        done = [e for e in entries if e["status"] == "done"]
        return {
            "name": self.grid.default_name(),
            "scenario": self.grid.scenario,
            "grid": self.grid.model_dump(mode="json"),
            "factors": list(self.grid.factors()),
            "size": self.size,
            "done": len(done),
            "successes": sum(1 for e in done if e["success"]),
            "episodes": entries,
        }

    def write_manifest(self) -> Path:
        """Rewrite manifest.json atomically."""
        path = self.root / MANIFEST_FILE
        write_json_atomic(path, self.manifest())
        return path


def plan(grid: GridSpec, root: Path) -> Ablation:
    """Expand the grid for the folder `root` (nothing is written)."""
    return Ablation(grid, Path(root), expand(grid))


def _finished(ep: Episode, run_dir: Path) -> dict[str, Any] | None:
    """The episode's summary when its folder holds a finished run of exactly this episode, else None."""
    summary_path = run_dir / SUMMARY_FILE
    try:
        summary = json.loads(summary_path.read_text(encoding="utf-8"))
        with open(run_dir / RUN_FILE, encoding="utf-8") as log:
            config = json.loads(log.readline())
    except (OSError, json.JSONDecodeError):
        return None
    if not isinstance(summary, dict) or not isinstance(config, dict) or "outcome" not in summary:
        return None
    reason = str(summary.get("reason") or "")
    if summary.get("cut_short") or reason.startswith(("crash", "interrupted")):
        return None
    task = config.get("task") or {}
    logged_backend = str(config.get("backend") or "")
    same = (
        str(task.get("id", "")).lower() == ep.task_id.lower()
        and config.get("start_pose_index") == ep.start_pose
        and config.get("options") == ep.options.model_dump(mode="json")
        # a backend spec may gain its default argument when logged ("local" -> "local:<model>")
        and (not logged_backend or logged_backend.split(":")[0] == ep.backend.split(":")[0])
    )
    return summary if same else None


def execute_episode(runner: Runner, spec: EpisodeSpec) -> tuple[dict[str, Any] | None, str | None, bool]:
    """Run one episode in whatever process this is: (summary, error, fatal).

    Bad input (a missing key, an absent model) is fatal: every other episode would fail the same way.
    Any other failure is recorded for this episode and the sweep goes on.
    """
    try:
        return runner(spec), None, False
    except BadInputError as err:
        return None, one_line(err), True
    except Exception as err:  # noqa: BLE001 — one broken episode must not end a long sweep
        text = str(err).splitlines()[0] if str(err) else ""
        return None, f"{type(err).__name__}: {text}" if text else type(err).__name__, False


def _default_runner() -> Runner:
    from llmnav.runner import run_episode

    return run_episode


ProgressCallback = Callable[[ManifestEntry, "Ablation"], None]


def run(
    ablation: Ablation,
    *,
    workers: int = 1,
    ray_address: str | None = None,
    runner: Runner | None = None,
    plots: bool = False,
    on_start: Callable[[int, int, int], None] | None = None,
    on_result: ProgressCallback | None = None,
) -> Ablation:
    """Run every unfinished episode; the manifest is rewritten after each one.

    `plots` writes each run's trajectory.png; off by default: drawing it cost more than a scripted
    episode itself, and the tables need only the logs and summaries.

    `on_start(total, already_done, successes)` is called once before any episode runs, `on_result` after
    each. `runner` (default `llmnav.runner.run_episode`) must be picklable for `workers > 1` and Ray.
    """
    runner = runner or _default_runner()
    root = ablation.root
    try:
        root.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise BadInputError(f"--out {root}: cannot create folder: {err.strerror or err}") from None
    pending: list[Episode] = []
    for ep in ablation.episodes:
        entry = ablation.entries[ep.key]
        summary = _finished(ep, root / ep.dir_name)
        if summary is not None:
            entry.record(summary)
            continue
        entry.status, entry.summary, entry.outcome, entry.success, entry.score = (
            "pending",
            None,
            None,
            None,
            None,
        )
        if (root / ep.dir_name).exists():  # cut short or inconsistent: start it afresh
            shutil.rmtree(root / ep.dir_name)
        pending.append(ep)
    ablation.write_manifest()
    if on_start is not None:
        done = [e for e in ablation.entries.values() if e.status == "done"]
        on_start(ablation.size, len(done), sum(1 for e in done if e.success))

    def settle(ep: Episode, result: tuple[dict[str, Any] | None, str | None, bool]) -> None:
        summary, error, fatal = result
        entry = ablation.entries[ep.key]
        if summary is not None:
            entry.record(summary)
        else:
            entry.status, entry.error = "error", error
        ablation.write_manifest()
        if on_result is not None:
            on_result(entry, ablation)
        if fatal:
            raise BadInputError(f"episode {ep.key}: {error}")

    specs = [(ep, ep.spec(root, ablation.grid.scenario, plots=plots)) for ep in pending]
    if ray_address is not None:
        for ep, result in _run_ray(runner, specs, ray_address):
            settle(ep, result)
    elif workers > 1 and len(specs) > 1:
        for ep, result in _run_pool(runner, specs, workers):
            settle(ep, result)
    else:
        for ep, spec in specs:
            settle(ep, execute_episode(runner, spec))
    return ablation


Result = tuple[dict[str, Any] | None, str | None, bool]

# Native thread pools a worker might start (BLAS, OpenMP, OpenCV, Mesa's llvmpipe): one thread each, so
# N workers on N cores do not oversubscribe them. Variables the user set win.
_WORKER_THREAD_VARS = (
    "OMP_NUM_THREADS",
    "OPENBLAS_NUM_THREADS",
    "MKL_NUM_THREADS",
    "OPENCV_FOR_THREADS_NUM",
    "LP_NUM_THREADS",
)


def worker_model_threads(workers: int) -> int:
    """Threads for an embedded model in each of `workers` processes (the local backend's measured rule)."""
    from llmnav.backends.local import pool_threads

    return pool_threads(workers)


def _init_worker(model_threads: int) -> None:
    """Pool worker start-up, before numpy, cv2 or a model is imported: cap the native thread pools."""
    from llmnav.backends.local import THREADS_ENV

    for name in _WORKER_THREAD_VARS:
        os.environ.setdefault(name, "1")
    os.environ.setdefault(THREADS_ENV, str(model_threads))


def _run_pool(
    runner: Runner, specs: Sequence[tuple[Episode, EpisodeSpec]], workers: int
) -> Iterator[tuple[Episode, Result]]:
    """Episodes in a spawn process pool (fresh interpreters: no inherited PyBullet or model state)."""
    import multiprocessing
    from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait

    context = multiprocessing.get_context("spawn")
    count = min(workers, len(specs))
    executor = ProcessPoolExecutor(
        max_workers=count,
        mp_context=context,
        initializer=_init_worker,
        initargs=(worker_model_threads(count),),
    )
    futures: dict[Future[Result], Episode] = {}
    try:
        for ep, spec in specs:
            futures[executor.submit(execute_episode, runner, spec)] = ep
        remaining = set(futures)
        while remaining:
            finished, remaining = wait(remaining, return_when=FIRST_COMPLETED)
            for future in finished:
                yield futures[future], future.result()
    finally:  # Ctrl-C or a fatal episode: drop what has not started, let running episodes end
        executor.shutdown(wait=True, cancel_futures=True)


def _run_ray(
    runner: Runner, specs: Sequence[tuple[Episode, EpisodeSpec]], address: str
) -> Iterator[tuple[Episode, Result]]:
    """Episodes as Ray tasks on an existing cluster (`auto`, `ray://host:10001`, `host:6379`)."""
    try:
        import ray
    except ImportError:
        raise BadInputError("--ray needs Ray: pip install 'llmnav[ray]'") from None
    try:
        if not ray.is_initialized():  # a caller (or a test) may have connected already
            ray.init(address=address or "auto", log_to_driver=False)
    except (ConnectionError, RuntimeError, ValueError) as err:
        raise BadInputError(
            f"--ray {address or 'auto'}: cannot connect: {str(err).splitlines()[0]}"
        ) from None
    remote = ray.remote(execute_episode)
    pending = {remote.remote(runner, spec): ep for ep, spec in specs}
    try:
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            for ref in ready:
                yield pending.pop(ref), ray.get(ref)
    finally:
        for ref in pending:
            ray.cancel(ref)


def results_runs(ablation: Ablation) -> list[Any]:
    """The finished episodes as `llmnav.score.Run`s (for the closing tables)."""
    from llmnav.score import load_run

    runs = []
    for ep in ablation.episodes:
        if ablation.entries[ep.key].status == "done":
            runs.append(load_run(ablation.root / ep.dir_name))
    return runs


def table_keys(ablation: Ablation) -> list[str]:
    """Condition keys the closing tables group by: the factors with more than one value."""
    return [name for name, values in ablation.grid.factors().items() if len(values) > 1]


def describe_episodes(episodes: Iterable[Episode]) -> list[list[str]]:
    """Rows for `--dry-run`: key, task, pose, trial, seed, backend."""
    return [
        [ep.key, ep.task_id, str(ep.start_pose), str(ep.trial), str(ep.seed), ep.backend] for ep in episodes
    ]
