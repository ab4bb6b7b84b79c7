"""The source papers' tables in their own rows and columns: `llmnav score DIRS --table NAME`.

`llmnav.scoring.score` builds llmnav's own tables (one row per task and condition, every metric a column). The
sources print theirs differently, and a reader comparing numbers needs the same layout (docs/sources.md,
docs/paper-tables.md):

- `stepwise-1` (stepwise source, Table 1): per task, iterations and latency (means), #JSON and #Safety
  (totals over the task's runs, as the source counts them), success k/N and the mean score;
- `stepwise-position` (Tables 3–7): the same per start position (Position 1–5) and condition, the factor
  of those tables;
- `waypoints-legs` (waypoint source, Tables 1–2): one row per leg of a route, each starting where the last
  ended (planning time, WGSR, replanning count, execution time, path length, collision Yes/No), and an
  Average row; a failed plan's execution and path are marked "failed" and left out of the average;
- `fsm-compare` (FSM source, Table 5 style): one row per metric, one column per condition (FSM-only,
  FSM + EMA, FSM + LLM), with the control-loop latency row and Welch's t / Hedges' g of the last condition
  against the first;
- `fsm-velocity` (FSM source, Table 4): statistics of the commanded v_x in APPROACH, for the baseline
  command, the accepted model suggestions and the fused command.

When the runs hold one condition, it is named in the title (oracle answers are marked there, never pooled
with a model's); with several, a leading Condition column tells them apart. Every table has records for
JSON and CSV (`llmnav.reporting.tables`).
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Callable, Sequence
from typing import Any

from llmnav.errors import BadInputError
from llmnav.reporting.velocity import well_formed_cmd
from llmnav.runs.folders import Run, load_scenario_of
from llmnav.runs.runlog import read_run
from llmnav.scoring.score import (
    CACHE_MARK,
    FAILED,
    MISSING,
    NA,
    ORACLE_MARK,
    Table,
    _fmt,
    _num,
    _stats_record,
    _task_sort_key,
    _values,
    condition_fields,
    condition_label,
    group_runs,
    installed_declarations,
    is_oracle,
    task_of_run,
)
from llmnav.scoring.stats import compare, describe
from llmnav.world.scenario import SEQUENCE_JOIN
from llmnav.world.tasks import sequence_legs

NOT_RUN = "not run"  # a leg after one that failed: the episode ended before it
START_LABEL = "SP"  # the start point, as the waypoint source names it


# --- shared helpers -----------------------------------------------------------------------------


def _conditions(runs: Sequence[Run], keys: Sequence[str]) -> list[tuple[str, list[Run]]]:
    """(condition label, runs) in a stable order (first appearance after sorting by label)."""
    return [(cond, group) for _task, cond, group in group_runs(runs, keys, by_task=False)]


def _titled(title: str, runs: Sequence[Run], keys: Sequence[str]) -> tuple[str, bool]:
    """The title, naming the only condition there is; and whether a Condition column is needed."""
    labels = {condition_label(r, keys) for r in runs}
    if len(labels) == 1:
        return f"{title} — {next(iter(labels))}", False
    return title, True


def _mean(values: Sequence[float], digits: int) -> str:
    return _fmt(sum(values) / len(values), digits) if values else MISSING


def _mean_sd(values: Sequence[float], digits: int) -> str:
    if not values:
        return MISSING
    d = describe(values)
    return _fmt(d.mean, digits) if d.n < 2 else f"{d.mean:.{digits}f} ± {d.sd:.{digits}f}"


def _total(runs: Sequence[Run], key: str) -> int | None:
    values = _values(runs, lambda r: r.summary.get(key))
    return int(sum(values)) if values else None


# --- stepwise source ----------------------------------------------------------------------------

STEPWISE_COLUMNS = ["Iterations", "Latency (s)", "#JSON", "#Safety", "Success", "Score"]


def _stepwise_cells(group: Sequence[Run]) -> tuple[list[str], dict[str, Any]]:
    """Table 1's cells for a group of runs: means of iterations and latency, totals of #JSON and #Safety."""
    iterations = _values(group, lambda r: r.summary.get("iterations"))
    latency = _values(group, lambda r: r.summary.get("latency_s_mean"))
    scores = _values(group, lambda r: r.summary.get("score"))
    successes = sum(1 for r in group if r.summary.get("success"))
    no_target = all(r.summary.get("task_kind") == "explore" for r in group)
    json_total, safety_total = _total(group, "json_errors"), _total(group, "safety_vetoes")
    cells = [
        _mean(iterations, 1),
        _mean(latency, 2),
        MISSING if json_total is None else str(json_total),
        MISSING if safety_total is None else str(safety_total),
        f"{successes}/{len(group)}",
        NA if no_target else _mean(scores, 2),
    ]
    record = {
        "n": len(group),
        "iterations": _stats_record(iterations),
        "latency_s": _stats_record(latency),
        "json_errors_total": json_total,
        "safety_vetoes_total": safety_total,
        "successes": successes,
        "score": None if no_target else _stats_record(scores),
    }
    return cells, record


def stepwise_table_1(runs: Sequence[Run], keys: Sequence[str]) -> Table | None:
    """Stepwise source, Table 1: per task (and condition), totals of #JSON and #Safety, means elsewhere."""
    if not runs:
        return None
    title, with_condition = _titled("Stepwise source, Table 1: per task", runs, keys)
    columns = [*(["Condition"] if with_condition else []), "Task", *STEPWISE_COLUMNS]
    rows, records = [], []
    for cond, by_condition in _conditions(runs, keys):
        for task, _cond, group in group_runs(by_condition, keys):
            cells, record = _stepwise_cells(group)
            rows.append([*([cond] if with_condition else []), task, *cells])
            records.append({"condition": cond, **condition_fields(group[0], keys), "task": task, **record})
    note = "Iterations, Latency, Score: means over the runs; #JSON, #Safety: totals over the runs; Success: k/N"
    return Table(title, columns, rows, records, note, name="stepwise-1")


def stepwise_position_table(runs: Sequence[Run], keys: Sequence[str]) -> Table | None:
    """Stepwise source, Tables 3–7: per start position and condition (the tables' factor)."""
    placed = [r for r in runs if isinstance(r.summary.get("start_pose_index"), int)]
    if not placed:
        return None
    tasks = sorted({r.task for r in placed}, key=_task_sort_key)
    title = f"Stepwise source, Tables 3–7: per start position (tasks {', '.join(tasks)})"
    columns = ["Condition", "Position", *STEPWISE_COLUMNS]
    rows, records = [], []
    for cond, group in _conditions(placed, keys):
        by_position: dict[int, list[Run]] = defaultdict(list)
        for run in group:
            by_position[int(run.summary["start_pose_index"])].append(run)
        for position in sorted(by_position):
            cells, record = _stepwise_cells(by_position[position])
            rows.append([cond, f"Position {position}", *cells])
            fields = condition_fields(group[0], keys)
            records.append({"condition": cond, **fields, "position": position, **record})
    note = "pooled over the tasks named; #JSON, #Safety: totals over the runs; others means; Success: k/N"
    return Table(title, columns, rows, records, note, name="stepwise-position")


# --- waypoint source ----------------------------------------------------------------------------

LEG_COLUMNS = ["Leg", "Planning time (s)", "WGSR (%)", "Replanning", "Execution time (s)", "Path length (m)",
               "Collision"]  # fmt: skip


def _legs(run: Run) -> list[dict[str, Any]]:
    """The run's leg records that carry the per-leg numbers (older runs logged only target and replans)."""
    legs = run.metrics.get("legs")
    return [leg for leg in legs if isinstance(leg, dict)] if isinstance(legs, list) else []


def _leg_names(run: Run, commands: Sequence[str]) -> list[str]:
    """What each leg of the run's task drives to, as the scenario labels it.

    The leg's first target's label; the command text where the scenario cannot be loaded or the target is
    a point.
    """
    scenario, _why = load_scenario_of(run.config)
    if scenario is None:
        return list(commands)
    try:
        legs = sequence_legs(scenario, task_of_run(scenario, run))
    except (KeyError, BadInputError):
        return list(commands)
    names = []
    for leg, command in zip(legs, commands, strict=False):
        first = leg.targets[0].object if leg.targets else None
        names.append(scenario.object(first).label if first and _has_object(scenario, first) else command)
    return names + list(commands[len(names) :])


def _has_object(scenario: Any, object_id: str) -> bool:
    return any(obj.id == object_id for obj in scenario.objects)


def _collided(leg: dict[str, Any]) -> bool:
    """A leg with a collision: a contact, or a reading below the critical distance (the source's events)."""
    return bool(leg.get("collided")) or (_num(leg.get("collision_events")) or 0) > 0


def _leg_values(legs: Sequence[dict[str, Any]], key: str, *, driven_only: bool = False) -> list[float]:
    """A leg field's values; `driven_only` leaves out failed plans (they drove nothing: no 0 s or 0 m)."""
    kept = [leg for leg in legs if not (driven_only and leg.get("plan_failed"))]
    return [v for v in (_num(leg.get(key)) for leg in kept) if v is not None]


def _wgsr(legs: Sequence[dict[str, Any]]) -> float | None:
    """Successful generations over attempts [%], pooled over the legs."""
    attempts = sum(_leg_values(legs, "generations"))
    return 100.0 * sum(_leg_values(legs, "valid_generations")) / attempts if attempts else None


def _leg_cells(legs: Sequence[dict[str, Any]], runs: int) -> tuple[list[str], dict[str, Any]]:
    """A leg row's cells after its label, from its records in `runs` runs (several for the Average row)."""
    if not legs:
        return [NOT_RUN, *([MISSING] * (len(LEG_COLUMNS) - 2))], {"legs": 0}
    failed = all(leg.get("plan_failed") for leg in legs)
    replans = _leg_values(legs, "replans")
    executed = _leg_values(legs, "execution_time_s", driven_only=True)
    driven = _leg_values(legs, "path_length_m", driven_only=True)
    collided = sum(1 for leg in legs if _collided(leg))
    wgsr = _wgsr(legs)
    single = len(legs) == 1
    cells = [
        _mean(_leg_values(legs, "planning_time_s"), 2),
        _fmt(wgsr, 1),
        (str(int(replans[0])) if single else _mean(replans, 1)) if replans else MISSING,
        FAILED if failed else _mean(executed, 2),
        FAILED if failed else _mean(driven, 2),
        MISSING if failed else (("Yes" if collided else "No") if single else f"{collided}/{len(legs)}"),
    ]
    record = {
        "legs": len(legs),
        "runs": runs,
        "plan_failed": sum(1 for leg in legs if leg.get("plan_failed")),
        "planning_time_s": _stats_record(_leg_values(legs, "planning_time_s")),
        "wgsr": wgsr,
        "replans_total": int(sum(replans)) if replans else None,
        "execution_time_s": _stats_record(executed),
        "path_length_m": _stats_record(driven),
        "collisions": collided,
    }
    return cells, record


def waypoint_legs_table(runs: Sequence[Run], keys: Sequence[str]) -> Table | None:
    """Waypoint source, Tables 1–2: one row per leg of each route (or command) and condition, then Average."""
    routed = [r for r in runs if _legs(r)]
    if not routed:
        return None
    title, with_condition = _titled("Waypoint source, Tables 1–2: per leg of the route", runs=routed, keys=keys)
    routes = {r.task for r in routed}
    with_route = len(routes) > 1
    columns = [*(["Condition"] if with_condition else []), *(["Route"] if with_route else []), *LEG_COLUMNS]
    rows, records = [], []
    for task, cond, group in group_runs(routed, keys):
        commands = str(group[0].summary.get("task_text") or "").split(SEQUENCE_JOIN)
        count = max(len(commands), *(len(_legs(r)) for r in group))
        lead = [*([cond] if with_condition else []), *([task] if with_route else [])]
        fields = {"condition": cond, **condition_fields(group[0], keys), "route": task}
        names = _leg_names(group[0], commands)
        previous = START_LABEL
        for index in range(count):
            legs = [_legs(r)[index] for r in group if index < len(_legs(r))]
            target = next((str(leg.get("target")) for leg in legs if leg.get("target")), None)
            here = names[index] if index < len(names) else (target or "?")
            label = f"{previous} → {here}"
            cells, record = _leg_cells(legs, len(group))
            rows.append([*lead, label, *cells])
            records.append({**fields, "leg": index + 1, "label": label, "target": target, **record})
            previous = here
        every = [leg for r in group for leg in _legs(r)]
        cells, record = _leg_cells(every, len(group))
        driven_legs = [leg for leg in every if not leg.get("plan_failed")]
        collided = sum(1 for leg in driven_legs if _collided(leg))
        # the Average row counts the driven legs with a collision (a failed plan drove nothing)
        cells[-1] = f"{collided}/{len(driven_legs)}" if driven_legs else MISSING
        rows.append([*lead, "Average", *cells])
        records.append({**fields, "leg": "average", "label": "Average", "target": None, **record})
    note = (
        "Replanning: replans per leg (a count; mean over runs when several); a failed plan's execution and path "
        f"are '{FAILED}' and left out of the Average; '{NOT_RUN}': the episode ended on an earlier leg; "
        "Collision: a contact or a reading below the 0.5 m critical distance"
    )
    return Table(title, columns, rows, records, note, name="waypoints-legs")


# --- FSM source ---------------------------------------------------------------------------------

ASSIST_NAMES = {"none": "FSM-only", "ema": "FSM + EMA", "llm": "FSM + LLM"}


def _fsm_runs(runs: Sequence[Run]) -> list[Run]:
    return [r for r in runs if "e_pos_m" in r.metrics]


def _fsm_conditions(runs: Sequence[Run], keys: Sequence[str]) -> list[tuple[str, list[Run]]]:
    """Conditions in the source's order (FSM-only, FSM + EMA, FSM + LLM); oracle answers before a model's.

    They are named as the source names them, FSM + LLM with its backend (or "oracle answers"), when those
    names tell every condition apart; otherwise by their full labels. So the t and g columns (last against
    first) compare a model with FSM-only, as the source does, whenever a model ran.
    """
    groups = _conditions(runs, keys)
    order = list(ASSIST_NAMES)

    def assist_of(group: Sequence[Run]) -> str:
        return str(group[0].metrics.get("assist"))

    def rank(item: tuple[str, list[Run]]) -> tuple[int, bool, str]:
        assist = assist_of(item[1])
        return (order.index(assist) if assist in order else len(order), not is_oracle(item[1][0]), item[0])

    groups.sort(key=rank)

    def name(group: Sequence[Run]) -> str:
        assist, backend = assist_of(group), group[0].summary.get("backend")
        named = ASSIST_NAMES.get(assist, "?")
        if assist == "llm" and backend:
            named += ORACLE_MARK if is_oracle(group[0]) else f" ({backend})"
        return named + (CACHE_MARK if group[0].summary.get("cache_hits") else "")  # as every condition label

    names = [name(group) for _, group in groups]
    if "?" in names or len(set(names)) < len(names):
        return groups
    return [(label, group) for label, (_, group) in zip(names, groups, strict=True)]


# (row label, record key, how to read one run, decimals): the rows of the comparison, in the source's order
FSM_ROWS: list[tuple[str, str, Callable[[Run], Any], int]] = [
    ("e_pos (m)", "e_pos_m", lambda r: r.metrics.get("e_pos_m"), 3),
    ("η = L_opt / L_real", "eta", lambda r: r.metrics.get("eta"), 3),
    ("Control-loop latency (ms)", "loop_latency_ms", lambda r: (r.metrics.get("tick_latency_ms") or {}).get("mean"), 2),
    ("Model latency (ms)", "model_latency_ms", lambda r: (r.metrics.get("model_latency_ms") or {}).get("mean"), 1),
    ("Acceptance r_acc", "r_acc", lambda r: r.metrics.get("r_acc"), 2),
    ("Utilisation r_use", "r_use", lambda r: r.metrics.get("r_use"), 2),
]


def fsm_compare_table(runs: Sequence[Run], keys: Sequence[str]) -> Table | None:
    """FSM source: a row per metric (control-loop latency included), a column per condition, then t and g."""
    fsm = _fsm_runs(runs)
    if not fsm:
        return None
    groups = _fsm_conditions(fsm, keys)
    contrast = len(groups) >= 2
    columns = ["Metric", *(label for label, _ in groups), *(["t", "p", "g"] if contrast else [])]
    rows = [["N", *(str(len(group)) for _, group in groups), *([""] * 3 if contrast else [])]]
    # tidy records: one per metric and condition; the contrast sits on the last condition's record
    records: list[dict[str, Any]] = []
    for row_label, key, read, digits in FSM_ROWS:
        values = [_values(group, read) for _, group in groups]
        row = [row_label, *(_mean_sd(v, digits) for v in values)]
        metric_records = [
            {"metric": key, "condition": label, **condition_fields(group[0], keys), "runs": len(group),
             **(_stats_record(v) or {"n": 0})}
            for (label, group), v in zip(groups, values, strict=True)
        ]  # fmt: skip
        if contrast:
            first, last = values[0], values[-1]
            if len(first) >= 2 and len(last) >= 2:
                c = compare(last, first)
                p = c.welch.p
                row += [_fmt(c.welch.t, 2), MISSING if math.isnan(p) else f"{p:.2g}", _fmt(c.hedges_g, 2)]
                metric_records[-1] |= {"against": groups[0][0], "t": _finite(c.welch.t), "df": _finite(c.welch.df),
                                       "p": _finite(p), "hedges_g": _finite(c.hedges_g)}  # fmt: skip
            else:
                row += [MISSING] * 3
        rows.append(row)
        records += metric_records
    note = "mean ± SD per run; Control-loop latency: tick start → command published"
    if contrast:
        note += f"; t (Welch), p, g (Hedges, small-sample corrected): {groups[-1][0]} against {groups[0][0]}"
    return Table("FSM source: conditions compared", columns, rows, records, note, name="fsm-compare")


def _finite(value: float) -> float | None:
    return value if value is not None and math.isfinite(value) else None


VELOCITY_ROWS = ("Baseline", "LLM (accepted)", "Fused")


def _velocity_samples(run: Run) -> dict[str, list[float]]:
    """v_x [m/s] of the run's sampled `cmd` records in APPROACH: baseline, accepted suggestion, fused command.

    The suggestion and the fused command count only where a suggestion was in force (the source's Table 4
    compares the three where the model acts).
    """
    samples: dict[str, list[float]] = {name: [] for name in VELOCITY_ROWS}
    try:
        events = read_run(run.run_dir).of_type("planner")
    except BadInputError:
        run.problem("no v_x statistics: the run log cannot be read")
        return samples
    for event in events:
        if event.get("kind") != "cmd" or event.get("state") != "APPROACH" or not well_formed_cmd(event):
            continue
        samples["Baseline"].append(float(event["base"][0]))
        if event.get("raw") is not None:
            samples["LLM (accepted)"].append(float(event["raw"][0]))
            samples["Fused"].append(float(event["fused"][0]))
    return samples


def fsm_velocity_table(runs: Sequence[Run], keys: Sequence[str]) -> Table | None:
    """FSM source, Table 4: statistics of the commanded v_x for the baseline, the accepted model and the fusion."""
    fsm = _fsm_runs(runs)
    if not fsm:
        return None
    groups = _fsm_conditions(fsm, keys)
    with_condition = len(groups) > 1
    title = "FSM source, Table 4: v_x in APPROACH" + ("" if with_condition else f" — {groups[0][0]}")
    columns = [*(["Condition"] if with_condition else []), "Signal", "Samples", "Mean (m/s)", "SD (m/s)",
               "Min (m/s)", "Max (m/s)"]  # fmt: skip
    rows, records = [], []
    for label, group in groups:
        pooled: dict[str, list[float]] = {name: [] for name in VELOCITY_ROWS}
        for run in group:
            for name, values in _velocity_samples(run).items():
                pooled[name] += values
        for name in VELOCITY_ROWS:
            values = pooled[name]
            d = describe(values) if values else None
            cells = [str(len(values))]
            if d is None:
                cells += [MISSING] * 4
            else:
                cells += [_fmt(d.mean, 4), _fmt(d.sd, 4), _fmt(min(values), 4), _fmt(max(values), 4)]
            rows.append([*([label] if with_condition else []), name, *cells])
            records.append({
                "condition": label, "signal": name, "samples": len(values),
                "mean": None if d is None else _finite(d.mean), "sd": None if d is None else _finite(d.sd),
                "min": min(values) if values else None, "max": max(values) if values else None,
            })  # fmt: skip
    note = "sampled cmd records in APPROACH, pooled over the runs; LLM and Fused where a suggestion was in force"
    return Table(title, columns, rows, records, note, name="fsm-velocity")


# --- registry -----------------------------------------------------------------------------------

PAPER_TABLES: dict[str, Callable[[Sequence[Run], Sequence[str]], Table | None]] = {
    "stepwise-1": stepwise_table_1,
    "stepwise-position": stepwise_position_table,
    "waypoints-legs": waypoint_legs_table,
    "fsm-compare": fsm_compare_table,
    "fsm-velocity": fsm_velocity_table,
}
# llmnav's own tables (`llmnav.scoring.tables.build_tables`, `--compare`) whatever the planners declare
OWN_TABLES = ("runs", "episodes", "path", "null_policies", "ceiling", "wording", "wording_spread", "failures",
              "aborted", "cost", "comparison")  # fmt: skip


def table_names() -> list[str]:
    """Every name `--table` accepts: llmnav's own tables, the installed planners' and the papers'."""
    declared = [spec.name for d in installed_declarations().values() for spec in d.score_tables]
    return list(dict.fromkeys([*OWN_TABLES, *declared, *PAPER_TABLES]))


def check_table_name(name: str) -> None:
    """BadInputError listing the names when `name` is no table."""
    names = table_names()
    if name not in names:
        raise BadInputError(f"--table {name}: unknown table (names: {', '.join(names)})")


def paper_table(name: str, runs: Sequence[Run], keys: Sequence[str]) -> Table:
    """The paper table `name` from the runs; BadInputError when no run has what it needs."""
    table = PAPER_TABLES[name](runs, keys)
    if table is None:
        need = {
            "stepwise-position": "a start pose",
            "waypoints-legs": "per-leg records (the waypoint planner's)",
            "fsm-compare": "FSM metrics",
            "fsm-velocity": "FSM metrics",
        }.get(name, "a result")
        raise BadInputError(f"--table {name}: no run here has {need}")
    return table
