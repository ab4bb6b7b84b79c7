"""Score tables that ask how much the model adds: null policies on the same episodes, and wordings.

- `null_policy_table`: beside each model condition (task × condition), the best null policy
  (`policy:first|random|keyword`) run on the same episodes — same scenario, task, wording, task text and
  start pose, same planner and options except the backend — with success and mean score of both on the
  episodes they share, the differences (Δ = model − policy) and n beside every mean. A row whose best
  policy does at least as well as the model says so in its own column: a planner that succeeds whatever
  the model answers shows up here, not in a footnote.
- `ceiling_table`: floor, model and ceiling on the same episodes: the best null policy, the model and the
  oracle answers (`policy:oracle`, what a perfect model would answer), and the share of the gap between
  floor and ceiling that the model closes, for success rate and for mean score.
- `wording_table` and `wording_spread_table`: success and score per task wording (bundled, paraphrase:K,
  free), and their spread across wordings, when runs record the wording.
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, TypeVar

from llmnav.backends.base import answerer
from llmnav.runs.folders import Run
from llmnav.scoring.metrics import condition_keys
from llmnav.scoring.score import (
    COMMON_COLUMNS,
    MISSING,
    Table,
    _hashable,
    _num,
    _task_sort_key,
    common_columns,
    condition_fields,
    condition_label,
    is_oracle,
)
from llmnav.scoring.stats import mean_sd

ALL_TASKS = "All tasks"
GAP_EPSILON = 1e-9  # a ceiling no further above the floor than rounding leaves no gap to close

Setting = tuple[Any, ...]
GroupKey = tuple[str, str, Setting]  # (task or ALL_TASKS, condition label, setting)
K = TypeVar("K", bound=tuple[Any, ...])


def is_policy(run: Run) -> bool:
    """Whether a null policy answered this run (the oracle's answers are no null policy: they know the truth)."""
    return answerer(str(run.summary.get("backend") or "")) == "policy"


def is_model(run: Run) -> bool:
    """Whether a model answered this run: a backend that is neither a null policy nor the oracle."""
    backend = str(run.summary.get("backend") or "")
    return bool(backend) and answerer(backend) == "model"


def _setting(run: Run) -> tuple[Any, ...]:
    """Everything of the condition but the backend: runs compared with a policy must agree on it."""
    condition = run.condition
    return tuple(_hashable(condition.get(k)) for k in condition_keys() if k != "backend")


@dataclass(frozen=True)
class Outcomes:
    """Success and score over a set of runs (score only where defined: explore tasks have none)."""

    n: int
    successes: int
    score_mean: float | None
    score_n: int
    spl_mean: float | None = None  # over the runs that have one (target tasks)
    soft_spl_mean: float | None = None
    collisions: int | None = None  # collision events summed; None when no run records a count

    @property
    def success_rate(self) -> float | None:
        """Share of successful runs."""
        return self.successes / self.n if self.n else None

    @classmethod
    def of(cls, runs: Sequence[Run]) -> Outcomes:
        """Tally `runs`."""
        scores = [v for v in (_num(r.summary.get("score")) for r in runs) if v is not None]
        mean, _, n_scores = mean_sd(scores)
        spl = [v for v in (_num(r.summary.get("spl")) for r in runs) if v is not None]
        soft = [v for v in (_num(r.summary.get("soft_spl")) for r in runs) if v is not None]
        counts = [int(v) for v in (_num(r.summary.get("collisions")) for r in runs) if v is not None]
        return cls(
            len(runs),
            sum(1 for r in runs if r.summary.get("success")),
            _finite(mean),
            n_scores,
            _finite(mean_sd(spl)[0]) if spl else None,
            _finite(mean_sd(soft)[0]) if soft else None,
            sum(counts) if counts else None,
        )

    def record(self) -> dict[str, Any]:
        """Raw numbers for JSON and CSV."""
        return {
            "n": self.n,
            "successes": self.successes,
            "success_rate": self.success_rate,
            "score_mean": self.score_mean,
            "score_n": self.score_n,
            "spl_mean": self.spl_mean,
            "soft_spl_mean": self.soft_spl_mean,
            "collisions": self.collisions,
        }

    def success_cell(self) -> str:
        """`k/n`."""
        return f"{self.successes}/{self.n}"

    def score_cell(self) -> str:
        """`0.45 (n=18)`: the mean with its n."""
        return MISSING if self.score_mean is None else f"{self.score_mean:.2f} (n={self.score_n})"


# Collisions, SPL and Soft-SPL of each side of a comparison, in one cell: "0.41 / 0.55 / 0.80".
SIDE_COLUMNS = ("Collisions", "SPL", "Soft-SPL")


def _side_cells(*sides: Outcomes) -> list[str]:
    """The SIDE_COLUMNS cells of several sides (model / null, or floor / model / ceiling); "—" where absent."""

    def joined(values: Iterable[float | int | None], digits: int) -> str:
        return " / ".join(MISSING if v is None else f"{v:.{digits}f}" for v in values)

    return [
        joined((s.collisions if s.n else None for s in sides), 0),
        joined((s.spl_mean if s.n else None for s in sides), 2),
        joined((s.soft_spl_mean if s.n else None for s in sides), 2),
    ]


def _finite(value: float | None) -> float | None:
    return value if value is not None and math.isfinite(value) else None


def _delta(a: float | None, b: float | None) -> float | None:
    return None if a is None or b is None else a - b


def _signed(value: float | None) -> str:
    return MISSING if value is None else f"{value:+.2f}"


@dataclass(frozen=True)
class PolicyResult:
    """One null policy against one model group, on the episodes both ran."""

    policy: str
    model: Outcomes
    null: Outcomes
    episodes: frozenset[tuple[Any, ...]]

    @property
    def rank(self) -> tuple[float, float]:
        """Best policy first: highest success rate, then highest mean score."""
        return (self.null.success_rate or 0.0, self.null.score_mean if self.null.score_mean is not None else -1.0)


def _against(model_runs: Sequence[Run], policy_runs: Sequence[Run]) -> PolicyResult | None:
    """Model and policy outcomes restricted to the episodes both ran (None when they share none)."""
    shared = frozenset({r.episode for r in model_runs} & {r.episode for r in policy_runs})
    if not shared:
        return None
    policy = str(policy_runs[0].summary.get("backend"))
    return PolicyResult(
        policy,
        Outcomes.of([r for r in model_runs if r.episode in shared]),
        Outcomes.of([r for r in policy_runs if r.episode in shared]),
        shared,
    )


def _null_policies(runs: Iterable[Run]) -> dict[Setting, dict[str, list[Run]]]:
    """The null-policy runs by setting, then by policy."""
    out: dict[Setting, dict[str, list[Run]]] = defaultdict(lambda: defaultdict(list))
    for run in runs:
        if is_policy(run):
            out[_setting(run)][str(run.summary.get("backend"))].append(run)
    return out


def _model_groups(runs: Iterable[Run], keys: Sequence[str]) -> dict[GroupKey, list[Run]]:
    """The model runs by task × condition × setting, with an 'All tasks' group per condition."""
    groups: dict[GroupKey, list[Run]] = defaultdict(list)
    for run in runs:
        if is_model(run):
            label = condition_label(run, keys)
            groups[(run.task, label, _setting(run))].append(run)
            groups[(ALL_TASKS, label, _setting(run))].append(run)
    return groups


def _on_task(runs: Iterable[Run], task: str) -> list[Run]:
    """The runs of `task` (every run for the 'All tasks' row)."""
    return list(runs) if task == ALL_TASKS else [r for r in runs if r.task == task]


def _policy_results(subject: Sequence[Run], task: str, policies: Mapping[str, Sequence[Run]]) -> list[PolicyResult]:
    """Each null policy of `task` against `subject` on the episodes both ran, by policy name."""
    results = [_against(subject, _on_task(runs, task)) for runs in policies.values()]
    return sorted((r for r in results if r is not None), key=lambda r: r.policy)


def _best(candidates: Sequence[PolicyResult]) -> PolicyResult | None:
    """The floor: highest success rate, then mean score; ties go to the alphabetically first policy."""
    return max(candidates, key=lambda c: c.rank) if candidates else None


def null_policy_table(runs: Sequence[Run], keys: Sequence[str]) -> Table | None:
    """See the module docstring; None when there is no model run with a matching null-policy run."""
    nulls = _null_policies(runs)
    groups = _model_groups(runs, keys)
    if not nulls or not groups:
        return None
    columns = [
        "Task", "Condition", "Model success", "Model score", "Best null policy", "Null success", "Null score",
        "Δ success", "Δ score", "Null ≥ model", "Every null policy (success, score)",
        *(f"{c} model / null" for c in SIDE_COLUMNS),
    ]  # fmt: skip
    rows, records = [], []
    for task, label, setting in _ordered(groups):
        group = groups[(task, label, setting)]
        candidates = _policy_results(group, task, nulls.get(setting, {}))
        best = _best(candidates)
        if best is None:
            continue
        d_success = _delta(best.model.success_rate, best.null.success_rate)
        d_score = _delta(best.model.score_mean, best.null.score_mean)
        matches = (d_success is not None and d_success <= 0) and (d_score is None or d_score <= 0)
        every = "; ".join(f"{c.policy} {c.null.success_cell()}, {c.null.score_cell()}" for c in candidates)
        rows.append(
            [
                task,
                label,
                best.model.success_cell(),
                best.model.score_cell(),
                best.policy,
                best.null.success_cell(),
                best.null.score_cell(),
                _signed(d_success),
                _signed(d_score),
                "YES" if matches else "no",
                every,
                *_side_cells(best.model, best.null),
            ]
        )
        records.append(
            {
                "task": task,
                "condition": label,
                **condition_fields(group[0], keys),
                "model": best.model.record(),
                "best_policy": best.policy,
                "null": best.null.record(),
                "delta_success_rate": d_success,
                "delta_score": d_score,
                "null_matches_model": matches,
                "policies": {c.policy: {"model": c.model.record(), "null": c.null.record()} for c in candidates},
            }
        )
    if not rows:
        return None
    note = (
        "model vs the best null policy on the episodes both ran (same scenario, task, wording, start pose and "
        "options); Δ = model − policy; 'Null ≥ model': the policy matched or beat the model"
    )
    return Table("Model vs null policies (same episodes)", columns, rows, records, note, name="null_policies")


# --- floor, model and ceiling -------------------------------------------------------------------


def _gap_closed(model: float | None, floor: float | None, ceiling: float | None) -> float | None:
    """(model − floor) / (ceiling − floor); None when a value is missing or the ceiling is not above the floor.

    A ceiling at or below the floor leaves no gap: any share of it would be a division by zero or a sign flip.
    """
    if model is None or floor is None or ceiling is None or ceiling - floor <= GAP_EPSILON:
        return None
    return (model - floor) / (ceiling - floor)


def _share_cell(value: float | None, n: int) -> str:
    """`50% (n=4)`, or "—" without a share."""
    return MISSING if value is None else f"{value:.0%} (n={n})"


def _cells(tally: Outcomes) -> list[str]:
    """Success and score cells; "—" for an empty side (no model run, no null policy on these episodes)."""
    return [tally.success_cell(), tally.score_cell()] if tally.n else [MISSING, MISSING]


def _oracle_groups(
    runs: Iterable[Run], keys: Sequence[str], models: Mapping[GroupKey, Sequence[Run]]
) -> tuple[dict[Setting, list[Run]], dict[GroupKey, list[Run]]]:
    """The oracle runs by setting, and the rows' groups.

    The groups are every model group, plus an empty one (labelled by the oracle's condition) for each task,
    and 'All tasks', of a setting that has oracle runs and no model run there.
    """
    oracles: dict[Setting, list[Run]] = defaultdict(list)
    groups = {key: list(group) for key, group in models.items()}
    with_model = {(task, setting) for task, _, setting in models}
    for run in runs:
        if not is_oracle(run):
            continue
        setting = _setting(run)
        oracles[setting].append(run)
        for task in (run.task, ALL_TASKS):
            if (task, setting) not in with_model:
                groups.setdefault((task, condition_label(run, keys), setting), [])
    return oracles, groups


@dataclass(frozen=True)
class Span:
    """Floor, model and ceiling on the episodes all three ran (an empty side: no runs there)."""

    floor_policy: str | None
    floor: Outcomes
    model: Outcomes
    ceiling: Outcomes
    episodes: int
    scored_episodes: int  # of those, the ones the model's runs have a score for (explore tasks have none)

    @property
    def gap_success(self) -> float | None:
        """Share of the floor-to-ceiling gap in success rate that the model closes."""
        return _gap_closed(self.model.success_rate, self.floor.success_rate, self.ceiling.success_rate)

    @property
    def gap_score(self) -> float | None:
        """Share of the floor-to-ceiling gap in mean score that the model closes."""
        return _gap_closed(self.model.score_mean, self.floor.score_mean, self.ceiling.score_mean)


def _span(
    task: str, model_runs: Sequence[Run], oracle_runs: Sequence[Run], policies: Mapping[str, Sequence[Run]]
) -> Span | None:
    """Floor, model and ceiling of `task` (or 'All tasks') restricted to shared episodes; None when none are.

    Without model runs the oracle's episodes are the subject, and a row needs a floor to say anything.
    """
    oracle = _on_task(oracle_runs, task)
    episodes = {r.episode for r in oracle}
    if model_runs:
        episodes &= {r.episode for r in model_runs}
    subject = [r for r in (model_runs or oracle) if r.episode in episodes]
    floor = _best(_policy_results(subject, task, policies))  # chosen on the episodes the ceiling has too
    if floor is not None:
        episodes &= floor.episodes
    if not episodes or (floor is None and not model_runs):
        return None
    model = [r for r in model_runs if r.episode in episodes]
    return Span(
        floor.policy if floor is not None else None,
        floor.null if floor is not None else Outcomes.of([]),
        Outcomes.of(model),
        Outcomes.of([r for r in oracle if r.episode in episodes]),
        len(episodes),
        len({r.episode for r in model if _num(r.summary.get("score")) is not None}),
    )


def _ceiling_row(
    task: str, label: str, span: Span, first: Run, keys: Sequence[str]
) -> tuple[list[str], dict[str, Any]]:
    """The displayed row and the raw record of one span; `first` gives the condition's fields."""
    row = [
        task,
        label,
        span.floor_policy or MISSING,
        *_cells(span.floor),
        *_cells(span.model),
        *_cells(span.ceiling),
        _share_cell(span.gap_success, span.episodes),
        _share_cell(span.gap_score, span.scored_episodes),
        *_side_cells(span.floor, span.model, span.ceiling),
    ]
    record = {
        "task": task,
        "condition": label,
        **condition_fields(first, keys),
        "floor_policy": span.floor_policy,
        "floor": span.floor.record(),
        "model": span.model.record(),
        "ceiling": span.ceiling.record(),
        "gap_closed_success": span.gap_success,
        "gap_closed_score": span.gap_score,
        "n": span.episodes,
        "n_score": span.scored_episodes,
    }
    return row, record


def ceiling_table(runs: Sequence[Run], keys: Sequence[str]) -> Table | None:
    """Floor (best null policy), model and ceiling (oracle answers) on the same episodes; None without oracle runs.

    Rows are the model groups of the null-policy table; a setting with oracle runs and null policies but no
    model run gets a row of its own (model cells "—"), so the span a model could cover is seen before any ran.
    """
    oracles, groups = _oracle_groups(runs, keys, _model_groups(runs, keys))
    if not oracles:
        return None
    nulls = _null_policies(runs)
    columns = [
        "Task", "Condition", "Floor: best null policy", "Floor success", "Floor score", "Model success",
        "Model score", "Oracle answers success", "Oracle answers score", "Gap closed: success", "Gap closed: score",
        *(f"{c} floor / model / ceiling" for c in SIDE_COLUMNS),
    ]  # fmt: skip
    rows, records = [], []
    for task, label, setting in _ordered(groups):
        model_runs, oracle_runs = groups[(task, label, setting)], oracles.get(setting, [])
        span = _span(task, model_runs, oracle_runs, nulls.get(setting, {}))
        if span is None:
            continue
        row, record = _ceiling_row(task, label, span, (model_runs or oracle_runs)[0], keys)
        rows.append(row)
        records.append(record)
    if not rows:
        return None
    note = (
        "floor: the best null policy; ceiling: oracle answers (policy:oracle, what a perfect model would answer, "
        "from the ground truth); all three on the episodes they share. Gap closed = (model − floor) / "
        "(ceiling − floor), n = shared episodes (with a score, for the score); — when the oracle answers do "
        "no better than the floor (no gap to close) or a side has no runs"
    )
    return Table("Floor, model and ceiling (same episodes)", columns, rows, records, note, name="ceiling")


def _by_wording(runs: Sequence[Run], keys: Sequence[str]) -> dict[tuple[str, str], dict[str, list[Run]]]:
    """(task, condition) -> wording -> runs, with an 'All tasks' entry per condition."""
    out: dict[tuple[str, str], dict[str, list[Run]]] = defaultdict(lambda: defaultdict(list))
    for run in runs:
        if run.wording is None:
            continue
        label = condition_label(run, keys)
        out[(run.task, label)][run.wording].append(run)
        out[(ALL_TASKS, label)][run.wording].append(run)
    return out


def _ordered(groups: Iterable[K]) -> list[K]:
    """Group keys `(task, label, ...)` in table order: by task number, 'All tasks' last, then by label."""
    return sorted(groups, key=lambda k: (k[0] == ALL_TASKS, _task_sort_key(k[0]), k[1]))


def _wording_order(wording: str) -> tuple[int, str]:
    return (0 if wording == "bundled" else 2 if wording == "free" else 1, wording)


def wording_table(runs: Sequence[Run], keys: Sequence[str]) -> Table | None:
    """Success and score per task × condition × wording; None when no run records its wording."""
    groups = _by_wording(runs, keys)
    if not groups:
        return None
    columns = ["Task", "Condition", "Wording", "Success", "Success rate", "Score", *COMMON_COLUMNS]
    rows, records = [], []
    for task, label in _ordered(groups):
        for wording in sorted(groups[(task, label)], key=_wording_order):
            group = groups[(task, label)][wording]
            tally = Outcomes.of(group)
            rate = tally.success_rate
            common_cells, common_fields = common_columns(group)
            rows.append(
                [task, label, wording, tally.success_cell(), MISSING if rate is None else f"{rate:.2f}",
                 tally.score_cell(), *common_cells]
            )  # fmt: skip
            records.append(
                {"task": task, "condition": label, **condition_fields(group[0], keys), "wording": wording}
                | tally.record()
                | common_fields
            )
    return Table("Success and score per task wording", columns, rows, records, name="wording")


def wording_spread_table(runs: Sequence[Run], keys: Sequence[str]) -> Table | None:
    """Spread of success rate and mean score across the wordings of each task × condition."""
    groups = _by_wording(runs, keys)
    if not groups:
        return None
    columns = ["Task", "Condition", "Wordings", "Success rate min–max", "Range", "SD", "Score min–max", "Range", "SD"]
    rows, records = [], []
    for task, label in _ordered(groups):
        tallies = [Outcomes.of(group) for group in groups[(task, label)].values()]
        rates = [t.success_rate for t in tallies if t.success_rate is not None]
        scores = [t.score_mean for t in tallies if t.score_mean is not None]
        first = next(iter(groups[(task, label)].values()))[0]
        record: dict[str, Any] = {"task": task, "condition": label, **condition_fields(first, keys)}
        record["wordings"] = len(tallies)
        cells = [task, label, str(len(tallies))]
        for name, values in (("success_rate", rates), ("score", scores)):
            _, sd, _ = mean_sd(values)
            low, high = (min(values), max(values)) if values else (None, None)
            spread = _delta(high, low)
            record |= {f"{name}_min": low, f"{name}_max": high, f"{name}_range": spread, f"{name}_sd": _finite(sd)}
            cells += [
                MISSING if low is None or high is None else f"{low:.2f}–{high:.2f}",
                MISSING if spread is None else f"{spread:.2f}",
                MISSING if _finite(sd) is None else f"{sd:.2f}",
            ]
        rows.append(cells)
        records.append(record)
    note = "spread of the per-wording success rates and mean scores (SD over wordings, n = wordings)"
    return Table("Spread across task wordings", columns, rows, records, note, name="wording_spread")
