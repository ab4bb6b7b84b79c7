"""What a planner declares for the layers above it: its score tables and how its run page reads its log.

A leaf module (imports nothing of llmnav): planners set one class attribute, `declares`, to a
`Declarations`, and `llmnav score` and `llmnav view` read it through the planner registry, so neither
names a planner. A planner that declares nothing gets `NOTHING_DECLARED` (the common tables and pages).

- `ScoreTable`: one table of `llmnav score` over the planner's own metrics; its `Column`s say where each
  value is read, how it is pooled over a group of runs and how it is shown.
- `ReferencePath`: the planner's successful runs are a yardstick in the path-length table (a column of
  their mean length per start pose, and every other run's ratio to it).
- `decision_noun`, `asks_model_every_decision`, `velocity_view`, `model_switch`: how `llmnav view`
  groups and annotates the planner's decisions.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

# How a column pools a group's runs:
# - mean_sd: mean ± SD of the per-run values (record: n, mean, sd, ci95);
# - median: median of the per-run values (record as for mean_sd);
# - rate: how many runs have a true value, shown `k/N` (record: the count);
# - share: pooled total of the values over the pooled total of the column's `per` metric, shown as a
#   percentage (record: `share_<key>`; the denominator's total is recorded once as `<per>`).
Aggregate = Literal["mean_sd", "median", "rate", "share"]
Source = Literal["metrics", "summary"]  # the planner's own metrics, or the summary every run has
RowLabel = Literal["task", "command"]  # the task id, or the task's wording (the command the robot got)


@dataclass(frozen=True)
class Column:
    """One column of a declared score table.

    `path` is read from `source` (default: `key`); a dotted path reads into a logged mapping, and a plain
    number where the mapping was expected stands for itself (a distribution logged as its mean alone).
    """

    key: str  # the record's field name (JSON and CSV)
    label: str  # the header, with its unit: "Planning (s)"
    aggregate: Aggregate = "mean_sd"
    digits: int = 2  # decimals shown
    source: Source = "metrics"
    path: str = ""  # where the value is read; "" = `key`
    per: str = ""  # share: the metric (in `source`) whose pooled total is the denominator
    # mean_sd and median: a run whose planner metric at this path is true is left out (a failed plan drove
    # nothing: its 0 s and 0 m are no execution); a group of such runs only shows `FAILED`
    unless: str = ""
    bounds: tuple[float | None, float | None] = (None, None)  # the metric's range: its 95 % interval stays inside

    @property
    def where(self) -> tuple[str, ...]:
        """The path's parts."""
        return tuple((self.path or self.key).split("."))


@dataclass(frozen=True)
class ScoreTable:
    """A table of `llmnav score` that a planner declares, built only when some run is covered.

    It covers the runs of every planner that declares it, and any run whose planner metrics hold
    `marker` (the runs of a planner that is not installed here still find their table).
    """

    name: str  # the `--table` id
    title: str
    columns: tuple[Column, ...]
    marker: str = ""  # a planner metric that puts a run in this table whatever its planner
    rows: RowLabel = "task"
    average_row: bool = False  # one more row per condition, pooled over every task
    note: str = ""


@dataclass(frozen=True)
class ReferencePath:
    """A planner whose successful runs' path lengths are a yardstick in the path-length table."""

    key: str  # record fields `<key>_length_m` and `<key>_ratio`
    label: str  # headers `<label> (m)` and `Ratio`


@dataclass(frozen=True)
class Declarations:
    """Everything a planner declares for the layers above it (see the module docstring)."""

    score_tables: tuple[ScoreTable, ...] = ()
    reference_path: ReferencePath | None = None
    decision_noun: str = "Step"  # what one logged step value is called on the run page: "Step 3", "Leg 1"
    # Every decision asks the model: the page marks a decision without a call, or a call without a verdict.
    asks_model_every_decision: bool = False
    # The planner commands velocities every tick: its page shows one decision per model suggestion (else
    # per state change) and the command profile, not one decision per logged step value.
    velocity_view: bool = False
    model_switch: str | None = None  # the option that turns the model on, named when it gave no answer


NOTHING_DECLARED = Declarations()


def declarations_of(planner_class: type | None) -> Declarations:
    """What `planner_class` declares (its `declares` attribute); NOTHING_DECLARED when it declares nothing."""
    found = getattr(planner_class, "declares", None)
    return found if isinstance(found, Declarations) else NOTHING_DECLARED
