"""`llmnav score`: read run folders, group them by task and condition, and build the sources' tables.

Pipeline: `find_run_dirs` (recursive) → `load_runs` (summary.json, or `summarize_run` for runs cut short) →
the tables: the episode and path-length tables every run has and the tables each planner declares (see
`llmnav.core.declarations`) here, the null-policy, floor/model/ceiling and wording tables in
`llmnav.scoring.policies`, all of them gathered by `llmnav.scoring.tables.build_tables` (only those with data);
and `compare_groups` (`--compare KEY=A KEY=B`). Rendering (rich, markdown, CSV, JSON) lives in
`llmnav.reporting.tables`. Tables are plain data (`Table`): formatted cells for display and raw numbers for
JSON and CSV. Whatever cannot be computed (a scenario that does not load, an oracle that fails) is noted on
its `Run` and listed by `problems`, never silently dropped.
"""

from __future__ import annotations

import math
import statistics
from collections import defaultdict
from collections.abc import Callable, Collection, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from llmnav.backends.base import answerer
from llmnav.core.declarations import Column, Declarations, ReferencePath, ScoreTable, declarations_of
from llmnav.core.geometry import Pose2D
from llmnav.errors import BadInputError, one_line
from llmnav.planners.base import planner_class, planner_names, planner_taking
from llmnav.runs.folders import (
    START_POSE_KEY,
    Run,
    load_scenario_of,
)
from llmnav.scoring.failures import FAILURE_CAUSES
from llmnav.scoring.metrics import (
    SUCCESS_RADIUS_M,
    condition_keys,
)
from llmnav.scoring.stats import Comparison, Describe, clip_interval, compare, describe, wilson_interval
from llmnav.world.scenario import SEQUENCE_JOIN
from llmnav.world.tasks import SEQUENCE_ID, sequence_legs, sequence_task, task_from_text

if TYPE_CHECKING:
    from llmnav.world.scenario import Scenario, Task

NA = "N.A."  # the task has no target to score against
MISSING = "—"  # no data: no summary has the value (baseline unavailable, ...); never a value that exists
ORACLE_MARK = " (oracle answers)"
FAILED = "failed"  # a failed plan's cell: the waypoint source leaves failed plans out of its averages
CACHE_MARK = " (from cache)"  # a run some of whose model answers came from the reply cache (`--cache`)


@dataclass
class Table:
    """A titled table: formatted rows for display, raw records for JSON."""

    title: str
    columns: list[str]
    rows: list[list[str]]
    records: list[dict[str, Any]] = field(default_factory=list)
    note: str = ""
    name: str = ""  # short id for `--table` (episodes, path, a planner's declared table, ...)


# --- grouping -----------------------------------------------------------------------------------


def _hashable(value: Any) -> Any:
    return tuple(value) if isinstance(value, list) else value


def varying_keys(runs: Sequence[Run]) -> list[str]:
    """Condition keys whose value differs across the runs (what a table's groups are told apart by)."""
    keys = []
    for key in condition_keys():
        if len({_hashable(r.condition.get(key)) for r in runs}) > 1:
            keys.append(key)
    return keys


def is_oracle(run: Run) -> bool:
    """Whether oracle answers (`policy:oracle`, computed from the ground truth) drove this run."""
    return answerer(str(run.summary.get("backend") or "")) == "oracle"


def condition_label(run: Run, keys: Sequence[str]) -> str:
    """`key=value, ...` over the varying keys ("all" when nothing varies); oracle runs are marked as such.

    The mark is part of the label even when the backend is not a grouping key, so oracle answers are never
    pooled with a model's and a reader never takes them for one. A run served (partly) from the reply cache
    is marked too: its answers were not asked of the model in this run, and its latencies are the first run's.
    """
    oracle = is_oracle(run)
    parts = [f"{k}={run.value(k)}{ORACLE_MARK if oracle and k == 'backend' else ''}" for k in keys]
    label = ", ".join(parts) or "all"
    label = label + ORACLE_MARK if oracle and "backend" not in keys else label
    return label + CACHE_MARK if run.summary.get("cache_hits") else label


def condition_fields(run: Run, keys: Sequence[str]) -> dict[str, Any]:
    """The grouping keys' values as separate record fields (tidy CSV: one column per condition key)."""
    return {k: run.value(k) for k in keys}


def _task_sort_key(task: str) -> tuple[Any, ...]:
    digits = "".join(ch for ch in task if ch.isdigit())
    return (task.rstrip("0123456789"), int(digits) if digits else -1, task)


def group_runs(runs: Sequence[Run], keys: Sequence[str], *, by_task: bool = True) -> list[tuple[str, str, list[Run]]]:
    """(task, condition label, runs) groups in a stable order (task number, then first appearance)."""
    groups: dict[tuple[str, str], list[Run]] = defaultdict(list)
    for run in runs:
        groups[(run.task if by_task else "all", condition_label(run, keys))].append(run)
    ordered = sorted(groups, key=lambda tc: (_task_sort_key(tc[0]), tc[1]))
    return [(task, cond, groups[(task, cond)]) for task, cond in ordered]


# --- formatting helpers -------------------------------------------------------------------------


def _num(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    return float(value) if math.isfinite(float(value)) else None


def _values(runs: Iterable[Run], get: Callable[[Run], Any]) -> list[float]:
    return [v for v in (_num(get(r)) for r in runs) if v is not None]


def _fmt(value: float | None, digits: int = 2) -> str:
    return MISSING if value is None or not math.isfinite(value) else f"{value:.{digits}f}"


def _mean_sd(values: Sequence[float], digits: int = 2) -> str:
    if not values:
        return MISSING
    d = describe(values)
    return _fmt(d.mean, digits) if d.n < 2 else f"{d.mean:.{digits}f} ± {d.sd:.{digits}f}"


def _median(values: Sequence[float]) -> str:
    return f"{statistics.median(values):.0f}" if values else MISSING


# Metric ranges [low, high] (None: unbounded): a confidence interval is cut to them, never impossible values.
UNIT_RANGE: tuple[float | None, float | None] = (0.0, 1.0)  # score, SPL, Soft-SPL
NON_NEGATIVE: tuple[float | None, float | None] = (0.0, None)  # counts, lengths, times, ratios of lengths


def _stats_record(
    values: Sequence[float], bounds: tuple[float | None, float | None] = NON_NEGATIVE
) -> dict[str, Any] | None:
    if not values:
        return None
    d = describe(values, bounds=bounds)
    clean = [None if not math.isfinite(x) else x for x in (d.mean, d.sd, d.ci_low, d.ci_high)]
    return {"n": d.n, "mean": clean[0], "sd": clean[1], "ci95": [clean[2], clean[3]]}


def _metric(name: str) -> Callable[[Run], Any]:
    return lambda run: run.metrics.get(name)


# --- the tables ---------------------------------------------------------------------------------


def episodes_table(runs: Sequence[Run], keys: Sequence[str]) -> Table | None:
    """Source A, Table 1 style, per task and condition: iterations, latency, #JSON, #Safety, k/N, score."""
    if not runs:
        return None
    columns = [
        "Task", "Condition", "N", "Iterations", "Latency (s)", "#JSON", "#Safety", "Success", "Score", "New tok",
        "Oracle SR", *COMMON_COLUMNS,
    ]  # fmt: skip
    rows, records = [], []
    for task, cond, group in group_runs(runs, keys):
        successes = sum(1 for r in group if r.summary.get("success"))
        scores = _values(group, lambda r: r.summary.get("score"))
        no_target = all(r.summary.get("task_kind") == "explore" for r in group)
        common_cells, common_fields = common_columns(group)
        reached = [bool(r.summary["oracle_success"]) for r in group if r.summary.get("oracle_success") is not None]
        fields = {
            "iterations": _values(group, lambda r: r.summary.get("iterations")),
            "latency_s": _values(group, lambda r: r.summary.get("latency_s_mean")),
            "new_prompt_tokens": _values(group, lambda r: r.summary.get("new_prompt_tokens_median")),
            "json_errors": _values(group, lambda r: r.summary.get("json_errors")),
            "safety_vetoes": _values(group, lambda r: r.summary.get("safety_vetoes")),
        }
        rows.append(
            [
                task,
                cond,
                str(len(group)),
                _mean_sd(fields["iterations"], 1),
                _mean_sd(fields["latency_s"], 2),
                # counted for every planner (a baseline's vetoes too): shown whenever a summary has them
                _mean_sd(fields["json_errors"], 1),
                _mean_sd(fields["safety_vetoes"], 1),
                f"{successes}/{len(group)}",
                NA if no_target else _mean_sd(scores, 2),
                _median(fields["new_prompt_tokens"]),
                f"{sum(reached)}/{len(reached)}" if reached else MISSING,
                *common_cells,
            ]
        )
        records.append(
            {
                "task": task,
                "condition": cond,
                **condition_fields(group[0], keys),
                "n": len(group),
                "successes": successes,
                "success_rate": successes / len(group),
                "success_rate_ci95": list(wilson_interval(successes, len(group))),
                "oracle_successes": sum(reached) if reached else None,
                "oracle_success_n": len(reached),
                "score": None if no_target else _stats_record(scores, UNIT_RANGE),
                **common_fields,
                **{name: _stats_record(vals) for name, vals in fields.items()},
            }
        )
    note = (
        "mean ± SD per run; New tok: median over runs of each run's median new prompt tokens per call; "
        f"Oracle SR: runs that came within the success radius at any time; {COMMON_NOTE}"
    ) + _radius_note(runs)
    return Table("Episodes (stepwise source, Table 1 style)", columns, rows, records, note, name="episodes")


# Columns every per-task table carries after its own (the episodes table and every declared table).
COMMON_COLUMNS = ("Collisions", "SPL", "Soft-SPL")
COMMON_NOTE = (
    "Collisions: collision events summed over the runs; SPL and Soft-SPL: mean ± SD per run, "
    "weighted by the shortest collision-free path (docs/metrics.md)"
)


def common_columns(group: Sequence[Run]) -> tuple[list[str], dict[str, Any]]:
    """The cells and record fields of COMMON_COLUMNS for a group: collisions, SPL and Soft-SPL.

    Collisions are the group's total (a record also holds how many runs had one); a group where no run
    records a count shows "—". SPL and Soft-SPL exist for target tasks only: "—" elsewhere.
    """
    counts = [int(c) for c in (_num(r.summary.get("collisions")) for r in group) if c is not None]
    spl = _values(group, lambda r: r.summary.get("spl"))
    soft = _values(group, lambda r: r.summary.get("soft_spl"))
    cells = [str(sum(counts)) if counts else MISSING, _mean_sd(spl, 2), _mean_sd(soft, 2)]
    fields = {
        "collisions": sum(counts) if counts else None,
        "runs_collided": sum(1 for c in counts if c > 0) if counts else None,
        "spl": _stats_record(spl, UNIT_RANGE),
        "soft_spl": _stats_record(soft, UNIT_RANGE),
    }
    return cells, fields


def _radius_note(runs: Sequence[Run]) -> str:
    """The note "; success within R m" when success was judged at a radius other than the default."""
    radii = {r for r in _values(runs, lambda run: run.summary.get("success_radius_m")) if r != SUCCESS_RADIUS_M}
    return f"; success within {', '.join(f'{r:g}' for r in sorted(radii))} m (--success-radius)" if radii else ""


def _start_key(run: Run) -> tuple[str, Any]:
    return (run.task, run.summary.get("start_pose_index"))


def _oracle_lengths(runs: Sequence[Run]) -> dict[tuple[str, Any], float | None]:
    """Oracle shortest-path length per (task, start pose); None where unavailable (noted on the run)."""
    lengths: dict[tuple[str, Any], float | None] = {}
    for run in runs:
        key = _start_key(run)
        if key in lengths:
            continue
        lengths[key] = None
        scenario, why = load_scenario_of(run.config)
        start = run.config.get("start_pose")
        if scenario is None:
            run.problem(f"no oracle path length: {why}")
            continue
        if start is None:
            run.problem("no oracle path length: the config line has no start_pose")
            continue
        try:
            lengths[key] = _num(sequence_oracle_length(scenario, task_of_run(scenario, run), Pose2D.from_list(start)))
        except Exception as err:  # noqa: BLE001 — shown as "—" in the table and reported, never fatal
            run.problem(f"no oracle path length: {type(err).__name__}: {one_line(err)}")
            continue
        if lengths[key] is None and run.summary.get("task_kind") == "target":  # others have no target: N.A.
            run.problem("no oracle path length: the oracle found no path from this start pose")
    return lengths


def task_of_run(scenario: Scenario, run: Run) -> Task:
    """The task a run drove: the scenario's (a route too) by id, else its logged text resolved again.

    A sequence of `--task` commands (id `SEQ`) and free text (id `adhoc`) are no scenario task: their text
    is (`llmnav.world.tasks`), so they are resolved from it as `drive` did.
    """
    try:
        return scenario.task(run.task)
    except KeyError:
        if run.summary.get("task_id") != SEQUENCE_ID and isinstance(run.config.get("task"), dict):
            return run.task_record(scenario)  # free text: the task as `drive` resolved it, targets included
        text = run.summary.get("task_text")
        if not isinstance(text, str) or not text:
            raise
    legs = text.split(SEQUENCE_JOIN) if run.task == SEQUENCE_ID else [text]
    tasks = [task_from_text(scenario, leg) for leg in legs]
    return tasks[0] if len(tasks) == 1 else sequence_task(scenario, tasks)


def sequence_oracle_length(scenario: Scenario, task: Task, start: Pose2D) -> float | None:
    """The oracle's path length [m]; for a route or sequence, summed over its legs (None if a leg has no path).

    Each leg starts where the oracle's previous one ended, as the robot's did where the last leg ended.
    """
    # deferred: the oracle path brings numpy (about 0.1 s), only for command sequences
    from llmnav.mapping.targets import oracle_path

    total, here = 0.0, start
    for leg in sequence_legs(scenario, task):
        path = oracle_path(scenario, leg, here)
        if path is None:
            return None
        total += path.length_m
        here = Pose2D(path.approach[0], path.approach[1], 0.0)
    return total


def reference_paths(declared: Mapping[str, Declarations] | None = None) -> dict[str, ReferencePath]:
    """Planner name -> the reference path it declares, for every installed planner that declares one."""
    declared = installed_declarations() if declared is None else declared
    return {name: d.reference_path for name, d in declared.items() if d.reference_path is not None}


def path_table(
    runs: Sequence[Run], keys: Sequence[str], references: Mapping[str, ReferencePath] | None = None
) -> Table | None:
    """Source A, Table 2 style, successful runs only: path length and its ratio to Oracle and to each reference.

    The references default to every installed planner's (see `llmnav.core.declarations.ReferencePath`).
    """
    successful = [r for r in runs if r.summary.get("success") and _num(r.summary.get("path_length_m")) is not None]
    if not successful:
        return None
    references = reference_paths() if references is None else references
    oracle = _oracle_lengths(successful)
    reference: dict[str, dict[tuple[str, Any], list[float]]] = {name: defaultdict(list) for name in references}
    for run in successful:
        if run.planner in reference:
            reference[run.planner][_start_key(run)].append(float(run.summary["path_length_m"]))
    columns = ["Task", "Condition", "N ok", "Path (m)", "Oracle (m)", "Ratio"]
    for ref in references.values():
        columns += [f"{ref.label} (m)", "Ratio"]
    columns += COMMON_COLUMNS
    rows, records = [], []
    for task, cond, group in group_runs(successful, keys):
        paths = _values(group, lambda r: r.summary.get("path_length_m"))
        oracle_m, oracle_ratio = [], []
        ref_m: dict[str, list[float]] = {name: [] for name in references}
        ref_ratio: dict[str, list[float]] = {name: [] for name in references}
        for run in group:
            path = float(run.summary["path_length_m"])
            o = oracle.get(_start_key(run))
            if o:
                oracle_m.append(o)
                oracle_ratio.append(path / o)
            for name in references:
                lengths = reference[name].get(_start_key(run))
                if lengths and run.planner != name:  # a reference is no yardstick for itself
                    mean = sum(lengths) / len(lengths)
                    ref_m[name].append(mean)
                    if mean > 0:
                        ref_ratio[name].append(path / mean)
        row = [task, cond, str(len(group)), _mean_sd(paths, 2), _mean_sd(oracle_m, 2), _mean_sd(oracle_ratio, 2)]
        record = {
            "task": task,
            "condition": cond,
            **condition_fields(group[0], keys),
            "n": len(group),
            "path_length_m": _stats_record(paths),
            "oracle_length_m": _stats_record(oracle_m),
            "oracle_ratio": _stats_record(oracle_ratio),
        }
        for name, ref in references.items():
            row += [_mean_sd(ref_m[name], 2), _mean_sd(ref_ratio[name], 2)]
            record[f"{ref.key}_length_m"] = _stats_record(ref_m[name])
            record[f"{ref.key}_ratio"] = _stats_record(ref_ratio[name])
        common_cells, common_fields = common_columns(group)
        rows.append(row + common_cells)
        records.append(record | common_fields)
    title = "Path length (stepwise source, Table 2 style; successful runs)"
    return Table(title, columns, rows, records, name="path")


def _read(run: Run, source: str, where: Sequence[str]) -> Any:
    """A value of the run's planner metrics or summary at a dotted path (see `llmnav.core.declarations.Column`)."""
    value: Any = run.metrics if source == "metrics" else run.summary
    for part in where:
        if not isinstance(value, dict):  # a number where a mapping was expected stands for itself
            break
        value = value.get(part)
    return value


def _reader(source: str, where: Sequence[str]) -> Callable[[Run], Any]:
    return lambda run: _read(run, source, where)


def _column_values(group: Sequence[Run], column: Column) -> list[float]:
    if column.unless:
        group = [r for r in group if not _read(r, "metrics", column.unless.split("."))]
    return _values(group, _reader(column.source, column.where))


def _all_left_out(group: Sequence[Run], column: Column) -> bool:
    """Whether the column's `unless` leaves out every run of the group (shown as FAILED, not as missing)."""
    return bool(column.unless) and all(_read(r, "metrics", column.unless.split(".")) for r in group)


def _declared_row(spec: ScoreTable, group: Sequence[Run]) -> tuple[list[str], dict[str, Any]]:
    """A group's cells (after its label, condition and N) and record fields (after its label, condition and n).

    Record fields come counts first (rates, the shares' denominators), then means, shares and medians,
    each in column order: the order of the CSV's columns.
    """
    cells: list[str] = []
    counts: dict[str, Any] = {}
    means: dict[str, Any] = {}
    shares: dict[str, Any] = {}
    medians: dict[str, Any] = {}
    for column in spec.columns:
        if column.aggregate == "rate":
            hits = sum(1 for r in group if _read(r, column.source, column.where))
            cells.append(f"{hits}/{len(group)}")
            counts[column.key] = hits
        elif column.aggregate == "share":
            total = sum(_values(group, _reader(column.source, (column.per,))))
            counts.setdefault(column.per, total)
            share = sum(_column_values(group, column)) / total if total else None
            cells.append(MISSING if share is None else f"{share:.0%}")
            shares[f"share_{column.key}"] = share
        elif column.aggregate == "median":
            values = _column_values(group, column)
            cells.append(f"{statistics.median(values):.{column.digits}f}" if values else MISSING)
            medians[column.key] = _stats_record(values, column.bounds)
        else:
            values = _column_values(group, column)
            cells.append(FAILED if _all_left_out(group, column) else _mean_sd(values, column.digits))
            means[column.key] = _stats_record(values, column.bounds)
    return cells, counts | means | shares | medians


def declared_table(
    spec: ScoreTable, runs: Sequence[Run], keys: Sequence[str], planners: Collection[str] = ()
) -> Table | None:
    """A planner's declared table over the runs it covers: those of `planners` and those holding its marker."""
    covered = [r for r in runs if r.planner in planners or (spec.marker and spec.marker in r.metrics)]
    if not covered:
        return None
    label_column = "Command" if spec.rows == "command" else "Task"
    columns = [label_column, "Condition", "N", *(c.label for c in spec.columns), *COMMON_COLUMNS]
    rows, records = [], []

    def add(label: str, cond: str, group: Sequence[Run]) -> None:
        cells, fields = _declared_row(spec, group)
        common_cells, common_fields = common_columns(group)
        rows.append([label, cond, str(len(group)), *cells, *common_cells])
        lead = {label_column.lower(): label, "condition": cond, **condition_fields(group[0], keys), "n": len(group)}
        records.append(lead | fields | common_fields)

    for task, cond, group in group_runs(covered, keys):
        add(str(group[0].summary.get("task_text") or task) if spec.rows == "command" else task, cond, group)
    if spec.average_row:
        for _task, cond, group in group_runs(covered, keys, by_task=False):
            add("Average", cond, group)
    return Table(spec.title, columns, rows, records, spec.note, name=spec.name)


def installed_declarations() -> dict[str, Declarations]:
    """What every installed planner declares, by planner name; one that fails to load is left out."""
    declared: dict[str, Declarations] = {}
    for name in planner_names():
        try:
            declared[name] = declarations_of(planner_class(name))
        except BadInputError:
            continue
    return declared


def declared_tables(runs: Sequence[Run], keys: Sequence[str], declared: Mapping[str, Declarations]) -> list[Table]:
    """Every table the planners declare that covers some run, in the order of the planners' names."""
    specs: dict[str, ScoreTable] = {}
    planners: dict[str, set[str]] = defaultdict(set)
    for name, declarations in declared.items():
        for spec in declarations.score_tables:
            specs.setdefault(spec.name, spec)
            planners[spec.name].add(name)
    tables = (declared_table(spec, runs, keys, planners[name]) for name, spec in specs.items())
    return [t for t in tables if t is not None]


def failures_table(runs: Sequence[Run], keys: Sequence[str]) -> Table | None:
    """Per condition: how many runs failed, and of what (`failure_cause`, see `llmnav.scoring.failures`).

    Every run counts, those aborted by a backend or server failure too (cause `outage`).
    """
    if not runs:
        return None
    rows, records = [], []
    for _task, cond, group in group_runs(runs, keys, by_task=False):
        causes = [r.summary.get("failure_cause") for r in group if not r.summary.get("success")]
        counts = {cause: causes.count(cause) for cause in FAILURE_CAUSES}
        rows.append([cond, str(len(group)), str(len(causes)), *(str(counts[c]) for c in FAILURE_CAUSES)])
        records.append(
            {"condition": cond, **condition_fields(group[0], keys), "n": len(group), "failed": len(causes), **counts}
        )
    return Table(
        "Failure causes (one per run that did not succeed)",
        ["Condition", "N", "Failed", *FAILURE_CAUSES],
        rows,
        records,
        note="docs/metrics.md defines each cause and the order they are tried in" + _radius_note(runs),
        name="failures",
    )


def collided_runs(runs: Sequence[Run]) -> list[str]:
    """One line per run that had a collision: its folder, how many and with what (`score` prints them)."""
    lines = []
    for run in runs:
        count = _num(run.summary.get("collisions"))
        if count is None or count <= 0:
            continue
        hit = run.summary.get("collided_with")
        what = f" with {', '.join(map(str, hit))}" if isinstance(hit, list) and hit else ""
        lines.append(f"{run.run_dir}: {int(count)} collision{'s' if count != 1 else ''}{what}")
    return lines


def aborted_table(aborted: Sequence[Run], keys: Sequence[str]) -> Table | None:
    """Per task and condition: the runs a backend or server failure or a crash ended, kept out of every mean."""
    if not aborted:
        return None
    rows, records = [], []
    for task, label, group in group_runs(aborted, keys):
        reasons = sorted({str(r.summary.get("reason") or "?") for r in group})
        more = f" (+{len(reasons) - 1} more)" if len(reasons) > 1 else ""
        rows.append([task, label, str(len(group)), reasons[0] + more])
        records.append({"task": task, "condition": label, **condition_fields(group[0], keys), "n": len(group),
                        "reasons": reasons})  # fmt: skip
    return Table(
        "Runs aborted by a backend or server failure or a crash (not in the means above)",
        ["Task", "Condition", "N", "Reason"],
        rows,
        records,
        note="No answer came from the model's server, or llmnav crashed: these runs say nothing about the model.",
        name="aborted",
    )


def select_table(tables: Sequence[Table], name: str) -> Table:
    """The table called `name` (`--table`); BadInputError naming the ones there are."""
    for table in tables:
        if table.name == name:
            return table
    there = ", ".join(["runs", *(t.name for t in tables)])  # `runs` (a row per run) is always there
    raise BadInputError(f"--table {name}: no such table for these runs (tables: {there})")


def problems(runs: Sequence[Run]) -> list[str]:
    """One line per thing that could not be computed, naming the run it came from."""
    return [f"{run.run_dir}: {text}" for run in runs for text in run.problems]


# --- comparisons --------------------------------------------------------------------------------

# The range of each compared metric (its interval is cut to it); success is a rate: Wilson's interval.
COMPARE_BOUNDS: dict[str, tuple[float | None, float | None]] = {
    "score": UNIT_RANGE, "success": UNIT_RANGE, "spl": UNIT_RANGE, "soft_spl": UNIT_RANGE, "wgsr": (0.0, 100.0),
}  # fmt: skip

# What `--compare` tests: name → how to read it from a run.
COMPARE_METRICS: dict[str, Callable[[Run], Any]] = {
    "score": lambda r: r.summary.get("score"),
    "success": lambda r: 1.0 if r.summary.get("success") else 0.0,
    "path_length_m": lambda r: r.summary.get("path_length_m"),
    "spl": lambda r: r.summary.get("spl"),
    "soft_spl": lambda r: r.summary.get("soft_spl"),
    "collisions": lambda r: r.summary.get("collisions"),
    "iterations": lambda r: r.summary.get("iterations"),
    "latency_s": lambda r: r.summary.get("latency_s_mean"),
    "e_pos_m": _metric("e_pos_m"),
    "eta": _metric("eta"),
    "planning_time_s": _metric("planning_time_s"),
    "wgsr": _metric("wgsr"),
}


def is_option_key(key: str) -> bool:
    """Whether some installed planner takes option `key` (so runs may be grouped or selected by it)."""
    return planner_taking(key) is not None


def parse_selector(text: str) -> tuple[str, str]:
    """`KEY=VALUE` of `--compare`; KEY a condition key or task/scenario."""
    key, sep, value = text.partition("=")
    key = key.strip().replace("-", "_")
    allowed = (*condition_keys(), START_POSE_KEY, "task", "scenario")
    if not sep or not key or not value:
        raise BadInputError(f"--compare {text!r}: expected KEY=VALUE, e.g. lidar_sectors=8")
    if key not in allowed and not is_option_key(key):
        raise BadInputError(f"--compare {text!r}: unknown key '{key}' (one of: {', '.join(allowed)})")
    return key, value.strip()


def _selected(run: Run, key: str, value: str) -> bool:
    if key == "task":
        actual: Any = run.task
    elif key == "scenario":
        actual = run.summary.get("scenario")
    else:
        actual = run.value(key)
    return str(actual).lower() == value.lower()


@dataclass
class GroupComparison:
    """One metric compared between two selections of runs."""

    metric: str
    result: Comparison


def compare_groups(runs: Sequence[Run], first: str, second: str) -> tuple[Table, list[GroupComparison]]:
    """Welch's t and Hedges' g for every metric that both selections have (at least 2 values each)."""
    key_a, value_a = parse_selector(first)
    key_b, value_b = parse_selector(second)
    group_a = [r for r in runs if _selected(r, key_a, value_a)]
    group_b = [r for r in runs if _selected(r, key_b, value_b)]
    for label, group in ((first, group_a), (second, group_b)):
        if not group:
            raise BadInputError(f"--compare {label}: no run matches")
    results = []
    for name, get in COMPARE_METRICS.items():
        a, b = _values(group_a, get), _values(group_b, get)
        if len(a) >= 2 and len(b) >= 2:
            c = compare(a, b)
            bounds = COMPARE_BOUNDS.get(name, NON_NEGATIVE)
            ranged = [_ranged(d, name == "success", bounds) for d in (c.a, c.b)]
            results.append(GroupComparison(name, Comparison(ranged[0], ranged[1], c.welch, c.hedges_g)))
    columns = ["Metric", f"{first} mean ± SD [95% CI]", f"{second} mean ± SD [95% CI]", "t", "df", "p", "g"]
    rows, records = [], []
    for item in results:
        c = item.result

        def cell(d: Any) -> str:
            return f"{d.mean:.3f} ± {d.sd:.3f} [{_fmt(d.ci_low, 3)}, {_fmt(d.ci_high, 3)}] (n={d.n})"

        p = c.welch.p
        rows.append(
            [
                item.metric,
                cell(c.a),
                cell(c.b),
                _fmt(c.welch.t, 2),
                _fmt(c.welch.df, 1),
                MISSING if math.isnan(p) else (f"{p:.2g}" if p >= 1e-4 else f"{p:.1e}"),
                _fmt(c.hedges_g, 2),
            ]
        )
        records.append(
            {
                "metric": item.metric,
                "a": {"selector": first, **_describe_record(c.a)},
                "b": {"selector": second, **_describe_record(c.b)},
                "t": _nan_none(c.welch.t),
                "df": _nan_none(c.welch.df),
                "p": _nan_none(p),
                "hedges_g": _nan_none(c.hedges_g),
            }
        )
    note = "Welch's t (two-sided p), Hedges' g with small-sample correction; positive = first group larger"
    return Table(f"Comparison: {first} vs {second}", columns, rows, records, note, name="comparison"), results


def _ranged(d: Describe, rate: bool, bounds: tuple[float | None, float | None]) -> Describe:
    """`d` with an interval inside the metric's range: Wilson's for a rate of 0/1 outcomes, else the t interval cut."""
    if rate:
        low, high = wilson_interval(round(d.mean * d.n), d.n, d.confidence)
    else:
        low, high = clip_interval(d.ci_low, d.ci_high, bounds)
    return Describe(d.n, d.mean, d.sd, low, high, d.confidence)


def _nan_none(value: float) -> float | None:
    return None if value is None or not math.isfinite(value) else value


def _describe_record(d: Any) -> dict[str, Any]:
    return {
        "n": d.n,
        "mean": _nan_none(d.mean),
        "sd": _nan_none(d.sd),
        "ci95": [_nan_none(d.ci_low), _nan_none(d.ci_high)],
    }
