"""Every table `llmnav score` builds from a set of runs, in the order it prints them.

llmnav's own, the planners' declared ones, the null policies' and ceiling's, the failures, the aborted
runs and the cost.

It sits above the modules that build each table (`llmnav.scoring.score`, `llmnav.scoring.policies`,
`llmnav.scoring.cost`), so none of them imports another back.
"""

from __future__ import annotations

from collections.abc import Sequence

from llmnav.runs.folders import Run, split_aborted
from llmnav.scoring.cost import cost_table
from llmnav.scoring.policies import ceiling_table, null_policy_table, wording_spread_table, wording_table
from llmnav.scoring.score import (
    Table,
    aborted_table,
    declared_tables,
    episodes_table,
    failures_table,
    installed_declarations,
    path_table,
    reference_paths,
    varying_keys,
)


def build_tables(runs: Sequence[Run], group_keys: Sequence[str] | None = None) -> list[Table]:
    """Every table that has data; groups are told apart by `group_keys` (default: the varying keys).

    The planners' own tables come from what each installed planner declares (`llmnav.core.declarations`);
    a run whose planner is not installed is in the common tables (and noted as a problem).
    """
    keys = list(group_keys) if group_keys is not None else varying_keys(runs)
    results, aborted = split_aborted(runs)
    declared = installed_declarations()
    for run in runs:
        if run.planner not in declared:
            run.problem(f"planner '{run.planner}' is not installed (or fails to load): its own tables are left out")
    common = (episodes_table(results, keys), path_table(results, keys, reference_paths(declared)))
    tables = [t for t in common if t is not None]
    tables += declared_tables(results, keys, declared)
    policies = (null_policy_table, ceiling_table, wording_table, wording_spread_table)
    tables += [t for t in (b(results, keys) for b in policies) if t is not None]
    tables += [t for t in (failures_table(runs, keys), aborted_table(aborted, keys)) if t is not None]
    tables += [t for t in (cost_table(runs, keys),) if t is not None]
    return tables
