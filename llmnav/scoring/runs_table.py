"""`llmnav score --table runs`: one row per run, streamed, for pandas and spreadsheets.

Pipeline: `iter_run_dirs` walks the folders in sorted order one directory at a time (no list of every
run) → `run_row` reads one run (`llmnav.runs.folders.run_from_record`: the same summary, rescoring and problems
as the aggregate tables) and flattens it into a row → `spool_rows` writes each row to a temporary JSON
Lines file while noting which columns hold a value → `write_rows` writes CSV, JSON or a Markdown/rich
table from the spool. Memory stays that of one run and the column names, whatever the number of runs;
a column empty in every row is left out (pandas would read it as NaN throughout).
"""

from __future__ import annotations

import csv
import json
import os
import tempfile
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

from llmnav.core.safefiles import SUMMARY_LIMIT, UnsafeFileError, read_text
from llmnav.core.safefiles import loads as bounded_loads
from llmnav.errors import BadInputError, one_line
from llmnav.runs.folders import Run, named_folder, run_from_record
from llmnav.runs.runlog import RUN_FILE, SUPERSEDED_FILE, dumps, read_run

if TYPE_CHECKING:
    from llmnav.backends.prices import PriceTable

TABLE_NAME = "runs"
MANIFEST_FILE = "manifest.json"  # an ablation folder's episode list (llmnav.ablate.manifest), read for trials
TITLE = "Runs (one row per run)"
NOTE = (
    "one row per run folder; options as logged; tokens summed over the run's model calls (where the backend "
    "counts them); cost_usd as llmnav priced the run (docs/cost-and-cache.md); a column empty in every row "
    "is left out"
)

# Shown by the terminal table (every column is in the CSV and JSON).
DISPLAY_COLUMNS = (
    "run", "scenario", "task", "start_pose_index", "trial", "planner", "backend", "outcome", "failure_cause",
    "success", "score", "spl", "path_length_m", "sim_time_s", "decisions",
)  # fmt: skip


# --- finding runs, one folder at a time ----------------------------------------------------------


def _walk_sorted(folder: Path, top: bool) -> Iterator[Path]:
    """Run folders at or below `folder`, depth first in name order; only one directory listing held per level."""
    try:
        entries = sorted(os.scandir(folder), key=lambda e: e.name)
    except OSError:
        return
    names = {e.name for e in entries if e.is_file(follow_symlinks=False)}
    if RUN_FILE in names and (top or SUPERSEDED_FILE not in names):
        yield folder.resolve()
    subfolders = [Path(e.path) for e in entries if e.is_dir(follow_symlinks=False)]
    del entries, names
    for sub in subfolders:
        yield from _walk_sorted(sub, False)


def iter_run_dirs(paths: Sequence[Path]) -> Iterator[Path]:
    """Every run folder at or below the given paths, like `llmnav.runs.folders.find_run_dirs` but streamed.

    A path inside another given path is skipped (its runs come with the outer one); an ablation's
    superseded attempts count only when named directly.
    """
    roots = [named_folder(path).resolve() for path in paths]
    kept = sorted({r for r in roots if not any(r != o and r.is_relative_to(o) for o in roots)})
    found = False
    for root in kept:
        for run_dir in _walk_sorted(root, True):
            found = True
            yield run_dir
    if not found:
        raise BadInputError(f"no run folders (with {RUN_FILE}) under {', '.join(str(p) for p in paths)}")


@lru_cache(maxsize=4)
def _trials(folder: Path) -> dict[str, int]:
    """Folder name → trial number from an ablation folder's manifest ({} when there is none)."""
    try:
        manifest = bounded_loads(read_text(folder / MANIFEST_FILE, limit=SUMMARY_LIMIT, root=folder))
    except (ValueError, OSError, UnsafeFileError):
        return {}
    episodes = manifest.get("episodes") if isinstance(manifest, dict) else None
    return {
        str(e["dir"]): int(e["trial"])
        for e in (episodes if isinstance(episodes, list) else ())
        if isinstance(e, dict) and isinstance(e.get("dir"), str) and isinstance(e.get("trial"), int)
    }


# --- one run, one row ----------------------------------------------------------------------------


def _tokens(events: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Prompt and completion tokens summed over the model calls.

    None where no call reported the count (a policy, a backend that does not count): unknown, not zero.
    """
    sums: dict[str, float | None] = {"prompt_tokens": None, "completion_tokens": None}
    for event in events:
        if event.get("type") != "llm_call":
            continue
        reply = event.get("reply")
        if not isinstance(reply, dict):
            continue
        for key in sums:
            value = reply.get(key)
            if isinstance(value, (int, float)) and not isinstance(value, bool):
                sums[key] = (sums[key] or 0) + value
    return sums


def _cell(value: Any) -> Any:
    """A logged option as one cell: a list as written on the command line (`lidar+image`), else as is."""
    if isinstance(value, list):
        if not value:
            return None  # no obstacles added, ...: nothing to show, so an all-empty column is left out
        return "+".join(map(str, value)) if all(not isinstance(v, (list, dict)) for v in value) else json.dumps(value)
    if isinstance(value, dict):
        return json.dumps(value, sort_keys=True)
    return value


def run_row(run: Run, events: Sequence[dict[str, Any]] = ()) -> dict[str, Any]:
    """One run as a flat record: what ran, how it ended, and what it cost."""
    summary, config = run.summary, run.config
    start = config.get("start_pose")
    start = start if isinstance(start, list) and len(start) >= 3 else [None, None, None]
    task_id = summary.get("task_id")
    row: dict[str, Any] = {
        "run": str(run.run_dir),
        "scenario": summary.get("scenario") or config.get("scenario"),
        "task": run.task,  # the id, or a free-text task's text: what the aggregate tables group by
        "task_id": None if run.task != task_id else task_id,
        "task_text": summary.get("task_text"),
        "task_kind": summary.get("task_kind"),
        "wording": run.wording,
        "start_pose_index": summary.get("start_pose_index"),
        "start_x_m": start[0],
        "start_y_m": start[1],
        "start_yaw_rad": start[2],
        "trial": _trials(run.run_dir.parent).get(run.run_dir.name),
        "seed": summary.get("seed", config.get("seed")),
        "planner": run.planner,
        "backend": summary.get("backend") or config.get("backend"),
        "outcome": summary.get("outcome"),
        "reason": summary.get("reason"),
        "failure_cause": summary.get("failure_cause"),
        "cut_short": summary.get("cut_short"),
        "success": summary.get("success"),
        "oracle_success": summary.get("oracle_success"),
        "score": summary.get("score"),
        "spl": summary.get("spl"),
        "soft_spl": summary.get("soft_spl"),
        "distance_m": summary.get("distance_m"),
        "path_length_m": summary.get("path_length_m"),
        "shortest_path_m": summary.get("shortest_path_m"),
        "collisions": summary.get("collisions"),
        "sim_time_s": summary.get("sim_time_s"),
        "wall_time_s": summary.get("wall_time_s"),
        "decisions": summary.get("iterations"),
        "llm_calls": summary.get("llm_calls"),
        "latency_s_mean": summary.get("latency_s_mean"),
        "json_errors": summary.get("json_errors"),
        "safety_vetoes": summary.get("safety_vetoes"),
        **_tokens(events),
        # as llmnav priced the run (docs/cost-and-cache.md): None with a note saying why when unknown
        "cost_usd": summary.get("cost_usd"),
        "cost_note": summary.get("cost_note"),
        "cache_hits": summary.get("cache_hits"),
    }
    for key, value in run.condition.items():  # the condition keys, then every other logged option
        if key not in row:
            row[key] = _cell(value)
    return row


# --- streaming through a spool -------------------------------------------------------------------


@dataclass
class Spool:
    """Rows written to a temporary JSON Lines file, the columns that hold a value, and what went wrong."""

    file: IO[str]
    count: int = 0
    columns: dict[str, bool] = field(default_factory=dict)  # name → some row has a value (first-seen order)
    broken: list[str] = field(default_factory=list)  # "folder: why" per run that could not be read
    problems: list[str] = field(default_factory=list)  # what could not be computed, per run

    def rows(self) -> Iterator[dict[str, Any]]:
        """The spooled rows, in order, read back one at a time."""
        self.file.seek(0)
        for line in self.file:
            yield json.loads(line)

    @property
    def filled(self) -> list[str]:
        """The columns some row has a value in."""
        return [name for name, has in self.columns.items() if has]


def spool_rows(
    paths: Sequence[Path],
    success_radius_m: float | None = None,
    progress: Callable[[int], None] | None = None,
    prices: PriceTable | None = None,
) -> Spool:
    """Read every run below `paths` into a spool (a temporary file, removed when closed).

    `success_radius_m` and `prices` (`--prices`): as for `llmnav.runs.folders.load_run`.
    """
    spool = Spool(tempfile.TemporaryFile("w+", encoding="utf-8", prefix="llmnav-runs-"))
    for run_dir in iter_run_dirs(paths):
        try:
            record = read_run(run_dir)
            run = run_from_record(record, success_radius_m, prices)
        except BadInputError as err:
            spool.broken.append(f"{run_dir}: {one_line(err)}")
            continue
        row = run_row(run, record.events)
        del record  # a long log is freed before the next one is read
        spool.problems += [f"{run.run_dir}: {text}" for text in run.problems]
        for key, value in row.items():
            if value is not None and value != "":  # an empty list of options reads as "" (nothing to show)
                spool.columns[key] = True
            else:
                spool.columns.setdefault(key, False)
        spool.file.write(dumps(row) + "\n")
        spool.count += 1
        if progress is not None:
            progress(spool.count)
    if spool.broken and not spool.count:
        spool.file.close()
        raise BadInputError(spool.broken[0].split(": ", 1)[-1])
    return spool


def write_csv(spool: Spool, out: IO[str]) -> None:
    """One CSV row per run (booleans as True/False, as pandas reads them)."""
    writer = csv.DictWriter(out, fieldnames=spool.filled, lineterminator="\n", restval="", extrasaction="ignore")
    writer.writeheader()
    for row in spool.rows():
        writer.writerow({k: "" if v is None else v for k, v in row.items()})


def write_json(spool: Spool, out: IO[str]) -> None:
    """`score --format json`'s shape: a list of tables, here one, its records written one at a time."""
    head = json.dumps({"name": TABLE_NAME, "title": TITLE, "note": NOTE})[:-1]
    out.write(f'[{head}, "records": [')
    filled = spool.filled
    for index, row in enumerate(spool.rows()):
        out.write(("," if index else "") + "\n" + json.dumps({k: row.get(k) for k in filled}, allow_nan=False))
    out.write("\n]}]\n")


def _md_cell(value: Any) -> str:
    text = "" if value is None else (f"{value:.4g}" if isinstance(value, float) else str(value))
    return text.replace("|", "\\|").replace("\n", " ")


def write_markdown(spool: Spool, out: IO[str], columns: Sequence[str] | None = None) -> None:
    """A Markdown table, row by row (`columns`: those to show, default every filled one)."""
    shown = [c for c in (columns or spool.filled) if c in spool.filled]
    out.write(f"### {TITLE}\n\n| " + " | ".join(shown) + " |\n|" + "|".join("---" for _ in shown) + "|\n")
    for row in spool.rows():
        out.write("| " + " | ".join(_md_cell(row.get(c)) for c in shown) + " |\n")
    out.write(f"\n_{NOTE}_\n")
