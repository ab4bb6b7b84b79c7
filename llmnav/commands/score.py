"""`llmnav score`: the sources' tables and statistics from run folders or ablation folders."""

from __future__ import annotations

import contextlib
import math
import sys
from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from llmnav.commands.common import chart_folder_option, check_output_path, cli_errors, console, err_console, esc
from llmnav.core.safefiles import atomic_text, write_text
from llmnav.errors import BadInputError

if TYPE_CHECKING:
    from llmnav.backends.prices import PriceTable
    from llmnav.scoring.score import Table


class OutputFormat(StrEnum):
    """How the tables are written."""

    rich = "rich"
    md = "md"
    csv = "csv"
    json = "json"


@cli_errors
def score(
    paths: Annotated[list[Path], typer.Argument(help="Run or ablation folders (searched recursively).")],
    compare: Annotated[
        list[str] | None,
        typer.Option("--compare", help="Two groups to compare: --compare KEY=A --compare KEY=B."),
    ] = None,
    by: Annotated[
        str | None,
        typer.Option(
            "--by",
            help="Group by these condition keys or start_pose (comma-separated); default: all keys that vary.",
        ),
    ] = None,
    fmt: Annotated[
        OutputFormat, typer.Option("--format", help="rich (terminal), md, csv (one table) or json.")
    ] = OutputFormat.rich,
    table: Annotated[
        str | None,
        typer.Option(
            "--table",
            help="Only this table: runs (one row per run, streamed), episodes, path, null_policies, ceiling, "
            "wording, wording_spread, failures, aborted, cost, comparison, one a planner declares (its name is in "
            "the JSON), or a source paper's in its own layout: stepwise-1, stepwise-position, waypoints-legs, "
            "fsm-compare, fsm-velocity (docs/paper-tables.md). CSV writes one table (default: the first).",
        ),
    ] = None,
    out: Annotated[Path | None, typer.Option("--out", help="Write the tables to this file.")] = None,
    plot: Annotated[Path | None, typer.Option("--plot", help="Write bar charts of score and success here.")] = None,
    prices: Annotated[
        Path | None,
        typer.Option("--prices", help="Reprice every run's model calls with this price table (TOML) from its log."),
    ] = None,
    success_radius: Annotated[
        float | None,
        typer.Option(
            "--success-radius",
            help="Judge success (and oracle success, SPL, Soft-SPL, failure causes) within this distance [m] "
            "of the target, recomputed from each run's log (default: 2.5, as recorded).",
        ),
    ] = None,
) -> None:
    """Turn run logs into the sources' tables: episodes, path length, each planner's own, null policies; statistics.

    Tables (or data) go to stdout; status and anything that could not be computed go to stderr.
    """
    # deferred: scoring brings pydantic and yaml (about 0.15 s), not for `llmnav --help`
    from llmnav.runs.folders import read_runs, split_aborted
    from llmnav.scoring.papers import PAPER_TABLES, check_table_name, paper_table
    from llmnav.scoring.score import collided_runs, compare_groups, problems, select_table, varying_keys
    from llmnav.scoring.tables import build_tables

    if table is not None:
        check_table_name(table)  # before any run is read: a typo costs nothing
    if out is not None:
        check_output_path(out, "--out", paths)
    chart_folder_option(plot)
    if success_radius is not None and not (math.isfinite(success_radius) and success_radius > 0):
        raise BadInputError(f"--success-radius {success_radius}: expected a distance in metres above 0")
    # deferred: the price table's module (about 4 ms with tomllib), not for `llmnav --help`
    from llmnav.backends.prices import load_prices

    checked = load_prices(prices)  # a bad $LLMNAV_PRICES is one line here, not a skipped run per old summary
    table_of_prices = checked if prices is not None else None
    if table == "runs":
        for flag, given in (("--compare", compare), ("--by", by), ("--plot", plot)):
            if given:
                raise BadInputError(f"--table runs: {flag} does not apply (it lists every run, ungrouped)")
        runs_table(paths, fmt, out, success_radius, table_of_prices)
        return
    runs, broken = read_runs(paths, success_radius, table_of_prices)
    keys = varying_keys(runs) if by is None else parse_keys(by)
    results, aborted = split_aborted(runs)
    # a paper's table alone: llmnav's own tables are not built (their oracle paths cost time)
    tables = [paper_table(table, results, keys)] if table in PAPER_TABLES else build_tables(runs, keys)
    if compare:
        if len(compare) != 2:
            raise BadInputError("--compare needs exactly two selections: --compare KEY=A --compare KEY=B")
        tables.append(compare_groups(results, compare[0], compare[1])[0])
    if table is not None and table not in PAPER_TABLES:
        tables = [select_table(tables, table)]
    elif fmt is OutputFormat.csv and tables:
        rest = ", ".join(t.name for t in tables[1:])
        if rest:
            err_console.print(f"[dim]csv: table '{tables[0].name}'; others with --table: {rest}[/]", highlight=False)
        tables = tables[:1]
    emit(tables, fmt, out)
    if plot is not None:
        # deferred: the chart module (about 4 ms; matplotlib later), only with --plot
        from llmnav.reporting.charts import plot_conditions

        written = plot_conditions(results, keys, plot)
        err_console.print(f"[dim]{len(written)} chart(s) written to {esc(plot)}[/]")
    for line in collided_runs(runs):  # every run that touched something, named: collisions are never pooled away
        err_console.print(f"[red]collided:[/] {esc(line)}", highlight=False, soft_wrap=True)
    for line in problems(runs):
        err_console.print(f"[yellow]not computed:[/] {esc(line)}", highlight=False, soft_wrap=True)
    for line in broken:
        err_console.print(f"[yellow]skipped:[/] {esc(line)}", highlight=False, soft_wrap=True)
    if aborted:
        err_console.print(
            f"[yellow]left out of the means:[/] {len(aborted)} run(s) aborted by a backend or server failure "
            "or a crash (table 'aborted' lists them per condition)",
            highlight=False,
            soft_wrap=True,
        )
    cut = sum(1 for r in runs if r.summary.get("cut_short"))
    err_console.print(f"[dim]{len(runs)} run(s) read{f', {cut} cut short' if cut else ''}[/]", highlight=False)


def runs_table(
    paths: list[Path], fmt: OutputFormat, out: Path | None, success_radius: float | None, prices: PriceTable | None
) -> None:
    """`--table runs`: a row per run, streamed through a spool file (see `llmnav.scoring.runs_table`)."""
    # deferred: scoring brings pydantic and yaml (about 0.15 s), not for `llmnav --help`
    from llmnav.scoring.runs_table import DISPLAY_COLUMNS, spool_rows, write_csv, write_json, write_markdown

    spool = spool_rows(paths, success_radius, prices=prices)
    with spool.file, contextlib.ExitStack() as stack:
        if fmt is OutputFormat.rich and out is None and spool.count <= RICH_ROWS:
            _print_runs(spool, DISPLAY_COLUMNS)
        else:
            try:
                stream = sys.stdout if out is None else stack.enter_context(atomic_text(out))
            except OSError as err:
                raise BadInputError(f"--out {out}: cannot write: {err.strerror or err}") from None
            if fmt is OutputFormat.csv:
                write_csv(spool, stream)
            elif fmt is OutputFormat.json:
                write_json(spool, stream)
            else:  # md, or more rows than a terminal table is worth: Markdown, the terminal's columns only
                write_markdown(spool, stream, None if fmt is OutputFormat.md else DISPLAY_COLUMNS)
            stream.flush()
        if out is not None:
            err_console.print(f"[dim]table written to {esc(out)}[/]")
        for line in spool.problems:
            err_console.print(f"[yellow]not computed:[/] {esc(line)}", highlight=False, soft_wrap=True)
        for line in spool.broken:
            err_console.print(f"[yellow]skipped:[/] {esc(line)}", highlight=False, soft_wrap=True)
        err_console.print(f"[dim]{spool.count} run(s) read[/]", highlight=False)


RICH_ROWS = 1000  # a terminal table above this many runs is written as Markdown rows (a rich table holds them all)


def _print_runs(spool: object, columns: tuple[str, ...]) -> None:
    """The runs as a rich table of the given columns (those some run has a value in)."""
    # deferred: scoring brings pydantic and yaml (about 0.15 s), not for `llmnav --help`
    from llmnav.reporting.tables import print_tables
    from llmnav.scoring.runs_table import NOTE, TITLE, Spool
    from llmnav.scoring.score import Table

    assert isinstance(spool, Spool)
    shown = [c for c in columns if c in spool.filled]
    rows = [["" if row.get(c) is None else _short(row.get(c)) for c in shown] for row in spool.rows()]
    print_tables(console, [Table(TITLE, shown, rows, note=NOTE + "; every column: --format csv or json", name="runs")])


def _short(value: object) -> str:
    if isinstance(value, float):
        return f"{value:.3g}"
    text = str(value)
    return Path(text).name if "/" in text and Path(text).is_absolute() else text


def parse_keys(text: str) -> list[str]:
    """`--by lidar_sectors,prompt` → validated condition keys."""
    # deferred: scoring brings pydantic and yaml (about 0.15 s), not for `llmnav --help`
    from llmnav.runs.folders import START_POSE_KEY
    from llmnav.scoring.metrics import condition_keys
    from llmnav.scoring.score import is_option_key

    keys = [k.strip().replace("-", "_") for k in text.split(",") if k.strip()]
    unknown = [k for k in keys if k not in (*condition_keys(), START_POSE_KEY) and not is_option_key(k)]
    if unknown:
        raise BadInputError(
            f"--by: unknown key '{unknown[0]}' (one of: {', '.join(condition_keys())}, {START_POSE_KEY}, "
            "or any planner option)"
        )
    return keys


def emit(tables: list[Table], fmt: OutputFormat, out: Path | None) -> None:
    """Print the tables in the chosen format, or write them to `out`; data formats print data only."""
    # deferred: the table printer (about 5 ms), not for `llmnav --help`
    from llmnav.reporting.tables import print_tables, render_text

    if fmt is OutputFormat.rich and out is None:
        print_tables(console, tables)
        return
    if fmt is OutputFormat.csv and not tables:
        text = ""
    else:
        text = render_text(tables, "md" if fmt is OutputFormat.rich else fmt.value)  # type: ignore[arg-type]
    if out is None:
        # Plain stdout, not rich: a data document must reach a pipe byte for byte (no wrapping, no markup).
        sys.stdout.write(text)
        sys.stdout.flush()
        return
    try:
        write_text(out, text)  # a fresh file renamed into place: never through a link at `out`
    except OSError as err:
        raise BadInputError(f"--out {out}: cannot write: {err.strerror or err}") from None
    err_console.print(f"[dim]tables written to {esc(out)}[/]")
