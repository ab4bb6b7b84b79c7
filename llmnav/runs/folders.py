"""Run folders as `llmnav score`, `view` and `ablate` read them.

Found below the given paths, each log read once, its summary taken from summary.json or recomputed from
the log (a run cut short), every problem noted on the run rather than dropped.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING, Any

from llmnav.backends.prices import load_prices, run_cost
from llmnav.errors import BadInputError, LlmnavError, one_line
from llmnav.runs.runlog import RUN_FILE, SUPERSEDED_FILE, RunRecord, read_run
from llmnav.scoring.metrics import RESCORED_KEYS, SUCCESS_RADIUS_M, aborted_without_result, summarize_run
from llmnav.world.scenario import Task, load_scenario
from llmnav.world.tasks import ADHOC_ID

if TYPE_CHECKING:
    from llmnav.backends.prices import PriceTable
    from llmnav.world.scenario import Scenario

START_POSE_KEY = "start_pose"  # `--by start_pose`: the stepwise source's Tables 3–7 report per start position


@dataclass
class Run:
    """One run folder as `score` sees it: its summary and its configuration line."""

    run_dir: Path
    summary: dict[str, Any]
    config: dict[str, Any]
    problems: list[str] = field(default_factory=list)  # what could not be computed for this run, and why

    @property
    def task(self) -> str:
        """Task id; a free-text task (typed, no scenario's id) by its text, so two of them are never pooled."""
        task_id = self.summary.get("task_id")
        text = self.summary.get("task_text")
        if text and (not task_id or task_id == ADHOC_ID or self.wording == "free"):
            return str(text)
        return str(task_id or text or "?")

    def task_record(self, scenario: Scenario) -> Task:
        """The run's task: the scenario's of its id, else the one its configuration line records (free text)."""
        task_id = str(self.summary.get("task_id") or "")
        if task_id and task_id != ADHOC_ID and self.wording != "free":
            return scenario.task(task_id)
        logged = self.config.get("task")
        if not isinstance(logged, dict):
            raise BadInputError("the config line records no task")
        fields = {k: logged[k] for k in ("id", "text", "kind", "difficulty", "targets") if k in logged}
        return Task.model_validate(fields)

    @property
    def condition(self) -> dict[str, Any]:
        """The run's condition values (llmnav.scoring.metrics.condition_keys), then every other logged option.

        Any planner option may be an ablation factor (`alpha`, `max_replans`, ...): its value comes from
        the configuration line, a list written as on the command line (`lidar+image`).
        """
        found = dict(self.summary.get("condition") or {})
        options = self.config.get("options")
        for key, value in options.items() if isinstance(options, dict) else ():
            if key not in found:
                found[key] = "+".join(map(str, value)) if isinstance(value, list) else value
        return found

    def value(self, key: str) -> Any:
        """A grouping key's value: a condition key, or `start_pose` (the 1-based start pose index)."""
        if key == START_POSE_KEY:
            return self.summary.get("start_pose_index")
        return self.condition.get(key)

    @property
    def planner(self) -> str:
        """Planner name."""
        return str(self.summary.get("planner") or self.condition.get("planner") or "?")

    @property
    def metrics(self) -> dict[str, Any]:
        """The planner's own metrics."""
        return dict(self.summary.get("planner_metrics") or {})

    @property
    def wording(self) -> str | None:
        """The task record's `wording` (bundled | paraphrase:K | free); None in runs that predate it."""
        task = self.config.get("task")
        value = task.get("wording") if isinstance(task, dict) else None
        return str(value) if value is not None else None

    @property
    def episode(self) -> tuple[Any, ...]:
        """What makes two runs the same episode: scenario, task, its wording and text, start pose."""
        return (
            self.summary.get("scenario"),
            self.task,
            self.wording,
            self.summary.get("task_text"),
            self.summary.get("start_pose_index"),
        )

    def problem(self, text: str) -> None:
        """Note something that could not be computed (reported on stderr by `llmnav score`)."""
        if text not in self.problems:
            self.problems.append(text)



# --- loading ------------------------------------------------------------------------------------


def named_folder(path: Path) -> Path:
    """The folder a path given on the command line names: itself, or the folder of the run.jsonl it is."""
    path = Path(path)
    if not path.exists():
        raise BadInputError(f"{path}: no such file or folder")
    if path.is_file():
        if path.name != RUN_FILE:
            raise BadInputError(f"{path}: not a run folder or ablation folder")
        return path.parent
    return path


def find_run_dirs(paths: Sequence[Path]) -> list[Path]:
    """Every run folder (a folder holding run.jsonl) at or below the given paths, sorted, deduplicated."""
    found: set[Path] = set()
    for given in paths:
        path = named_folder(given)
        if path != Path(given):  # a run.jsonl named directly: that one run
            found.add(path.resolve())
            continue
        found.update(
            p.parent.resolve()
            for p in path.rglob(RUN_FILE)
            # an ablation's superseded attempts (kept, not results) count only when named directly
            if p.parent == path or not (p.parent / SUPERSEDED_FILE).exists()
        )
    if not found:
        raise BadInputError(f"no run folders (with {RUN_FILE}) under {', '.join(str(p) for p in paths)}")
    return sorted(found)


@lru_cache(maxsize=16)
def _scenario(name_or_path: str) -> Scenario | str:
    """The scenario, or why it cannot be loaded (cached either way: many runs share one)."""
    try:
        return load_scenario(name_or_path)
    except (LlmnavError, OSError) as err:
        return one_line(err)


def load_scenario_of(config: dict[str, Any]) -> tuple[Scenario | None, str | None]:
    """The run's scenario (its recorded file, else its bundled name), or None and why not."""
    reasons = []
    for key in ("scenario_file", "scenario"):
        value = config.get(key)
        if value:
            loaded = _scenario(str(value))
            if not isinstance(loaded, str):
                return loaded, None
            reasons.append(f"scenario '{value}' cannot be loaded: {loaded}")
    return None, ("; ".join(reasons) or "the config line names no scenario")


def scenario_of(config: dict[str, Any]) -> Scenario | None:
    """The run's scenario; None when it cannot be loaded (see `load_scenario_of` for why)."""
    return load_scenario_of(config)[0]


# Keys a summary written before collisions, SPL and failure causes were recorded lacks: computed from the log.
_COLLISION_KEYS = ("collisions", "collided_with")


def load_run(run_dir: Path, success_radius_m: float | None = None, prices: PriceTable | None = None) -> Run:
    """A run's summary: summary.json when the run ended, else computed from its (cut-short) log.

    `success_radius_m` [m]: success, oracle success, SPL, Soft-SPL and the failure cause are recomputed from
    the log at this radius (`--success-radius`). A summary written before some of these keys existed gets
    them computed from its log the same way (`llmnav.scoring.metrics.summarize_run`). `prices` (`--prices`): the
    cost is recomputed from the log with this table instead of the one the run was priced with.
    """
    return run_from_record(read_run(run_dir), success_radius_m, prices)


def run_from_record(
    record: RunRecord, success_radius_m: float | None = None, prices: PriceTable | None = None
) -> Run:
    """`load_run` of a log already read (the per-run table also sums the log's token counts)."""
    run_dir = record.run_dir
    summary = record.summary
    problems = []
    if summary is None or "outcome" not in summary:
        scenario, why = load_scenario_of(record.config)
        if scenario is None:
            problems.append(f"{why}; its targets are scored only where the log records them as points")
        summary = summarize_run(record, scenario, success_radius_m=success_radius_m or SUCCESS_RADIUS_M)
    else:
        missing = [k for k in (*RESCORED_KEYS, *_COLLISION_KEYS) if k not in summary]
        if success_radius_m is not None or missing:
            scenario, why = load_scenario_of(record.config)
            fresh = summarize_run(record, scenario, success_radius_m=success_radius_m or SUCCESS_RADIUS_M)
            redo = RESCORED_KEYS if success_radius_m is not None else ()
            if "collided_with" in missing:  # older counts missed contacts only the end reason reported
                redo = (*redo, *_COLLISION_KEYS, "failure_cause")
            summary = {**summary, **{k: fresh[k] for k in dict.fromkeys((*missing, *redo))}}
            if scenario is None and summary.get("task_kind") == "target":
                problems.append(f"{why}; no SPL or Soft-SPL")
    if "cost_usd" not in summary or prices is not None:  # a summary from before costs were: priced now

        summary = {**summary, **run_cost(record.config, record.of_type("llm_call"), prices or load_prices())}
    # An outage has no score by design (it is tabled apart): only a scored run without one is a problem.
    if summary.get("task_kind") == "target" and summary.get("score") is None and not aborted_without_result(summary):
        problems.append("no score: the task's targets could not be resolved")
    return Run(Path(run_dir), summary, record.config, problems)


def load_runs(paths: Sequence[Path], success_radius_m: float | None = None) -> list[Run]:
    """Every run below the given paths (BadInputError at the first that cannot be read)."""
    return [load_run(d, success_radius_m) for d in find_run_dirs(paths)]


def read_runs(
    paths: Sequence[Path], success_radius_m: float | None = None, prices: PriceTable | None = None
) -> tuple[list[Run], list[str]]:
    """Every readable run below the given paths, and "folder: why" for each that is not.

    One damaged log among thousands must not cancel the tables of the rest; when none can be read, the
    first one's error is raised (a single broken run named on the command line is an error).
    `success_radius_m` and `prices`: as for `load_run`.
    """
    runs: list[Run] = []
    broken: list[tuple[Path, BadInputError]] = []
    for run_dir in find_run_dirs(paths):
        try:
            runs.append(load_run(run_dir, success_radius_m, prices))
        except BadInputError as err:
            broken.append((run_dir, err))
    if broken and not runs:
        raise broken[0][1]

    return runs, [f"{run_dir}: {one_line(err)}" for run_dir, err in broken]


def split_aborted(runs: Sequence[Run]) -> tuple[list[Run], list[Run]]:
    """(the model's results, the runs aborted by a server failure or a crash): the latter never enter a mean."""
    results = [r for r in runs if not aborted_without_result(r.summary)]
    return results, [r for r in runs if aborted_without_result(r.summary)]
