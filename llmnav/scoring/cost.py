"""The cost table (`llmnav score --table cost`): model calls, cache hits, tokens and US dollars per condition.

Every run counts, those aborted by a server failure too (their calls were paid). A run's `cost_usd` comes
from its summary (`llmnav.backends.prices`): 0 for free backends, None when its model has no price. A
condition with a run of unknown cost shows the dollars of the runs that have one and says how many do
not, never a total that looks complete. The last row is the whole set of runs (the sweep).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from llmnav.backends.prices import billing_of
from llmnav.runs.folders import Run
from llmnav.scoring.score import MISSING, Table, condition_fields, group_runs

COLUMNS = ["Condition", "N", "Calls", "Cache hits", "Prompt tokens", "Completion tokens", "Cost [USD]", "USD/run"]
ALL_RUNS = "all runs"


def _int(value: Any) -> int:
    return value if isinstance(value, int) and not isinstance(value, bool) else 0


def cost_record(runs: Sequence[Run]) -> dict[str, Any]:
    """Calls, cache hits, tokens and cost [USD] summed over runs; `cost_usd` None when any run's is unknown."""
    tokens = [r.summary.get("tokens") or {} for r in runs]
    costs = [r.summary.get("cost_usd") for r in runs]
    known = [float(c) for c in costs if isinstance(c, (int, float)) and not isinstance(c, bool)]
    unknown = len(costs) - len(known)
    return {
        "n": len(runs),
        "llm_calls": sum(_int(r.summary.get("llm_calls")) for r in runs),
        "cache_hits": sum(_int(r.summary.get("cache_hits")) for r in runs),
        "prompt_tokens": sum(_int(t.get("prompt")) for t in tokens),
        "completion_tokens": sum(_int(t.get("completion")) for t in tokens),
        "paid_prompt_tokens": sum(_int(t.get("paid_prompt")) for t in tokens),
        "paid_completion_tokens": sum(_int(t.get("paid_completion")) for t in tokens),
        "cost_usd": round(sum(known), 6) if not unknown else None,
        "cost_known_usd": round(sum(known), 6),
        "runs_cost_unknown": unknown,
        "notes": sorted({str(r.summary.get("cost_note")) for r in runs if r.summary.get("cost_note")}),
    }


def _money(record: dict[str, Any]) -> tuple[str, str]:
    if record["cost_usd"] is not None:
        total = record["cost_usd"]
        return f"{total:.4f}", f"{total / record['n']:.4f}" if record["n"] else MISSING
    return f"{record['cost_known_usd']:.4f} + unknown ({record['runs_cost_unknown']} run(s))", MISSING


def _row(label: str, record: dict[str, Any]) -> list[str]:
    keys = ("n", "llm_calls", "cache_hits", "prompt_tokens", "completion_tokens")
    return [label, *(str(record[k]) for k in keys), *_money(record)]


def asks_a_server(run: Run) -> bool:
    """Whether the run's calls went to a model API (priced or not) or its reply cache.

    The local engine, policies and replays bill nothing and send nothing: a cost table of theirs is noise.
    """
    return "free" not in billing_of(run.config) or bool(run.summary.get("cache_hits"))


def cost_table(runs: Sequence[Run], keys: Sequence[str]) -> Table | None:
    """Per condition, then for all runs: calls, cache hits, tokens and cost.

    None when no run asked a model API (`asks_a_server`).
    """
    if not any(_int(r.summary.get("llm_calls")) and asks_a_server(r) for r in runs):
        return None
    rows, records = [], []
    for _task, cond, group in group_runs(runs, keys, by_task=False):
        record = cost_record(group)
        rows.append(_row(cond, record))
        records.append({"condition": cond, **condition_fields(group[0], keys), **record})
    whole = cost_record(runs)
    rows.append(_row(ALL_RUNS, whole))
    records.append({"condition": ALL_RUNS, **whole})
    notes = sorted({n for r in records for n in r["notes"]})
    return Table(
        "Cost of the model calls (tokens × docs/cost-and-cache.md's price table; cache hits cost nothing)",
        COLUMNS,
        rows,
        records,
        note="; ".join(notes[:4]) + (f"; +{len(notes) - 4} more" if len(notes) > 4 else ""),
        name="cost",
    )
