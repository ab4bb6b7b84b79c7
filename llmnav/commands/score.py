"""`llmnav score`: the sources' tables and statistics from run folders or ablation folders."""

from __future__ import annotations

from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from llmnav.commands.common import chart_folder_option, check_output_path, cli_errors, console, esc
from llmnav.errors import BadInputError

if TYPE_CHECKING:
    from llmnav.score import Table


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
        typer.Option("--by", help="Group by these condition keys (comma-separated); default: all that vary."),
    ] = None,
    fmt: Annotated[
        OutputFormat, typer.Option("--format", help="rich (terminal), md, csv or json.")
    ] = OutputFormat.rich,
    out: Annotated[Path | None, typer.Option("--out", help="Write the tables to this file.")] = None,
    plot: Annotated[
        Path | None, typer.Option("--plot", help="Write bar charts of score and success here.")
    ] = None,
) -> None:
    """Turn run logs into the sources' tables: episodes, path length, waypoints, FSM; plus statistics."""
    from llmnav.score import build_tables, compare_groups, load_runs, varying_keys

    if out is not None:
        check_output_path(out, "--out", paths)
    chart_folder_option(plot)
    runs = load_runs(paths)
    keys = varying_keys(runs) if by is None else parse_keys(by)
    tables = build_tables(runs, keys)
    if compare:
        if len(compare) != 2:
            raise BadInputError("--compare needs exactly two selections: --compare KEY=A --compare KEY=B")
        tables.append(compare_groups(runs, compare[0], compare[1])[0])
    emit(tables, fmt, out)
    if plot is not None:
        from llmnav.reporting.charts import plot_conditions

        written = plot_conditions(runs, keys, plot)
        console.print(f"[dim]{len(written)} chart(s) written to {esc(plot)}[/]")
    cut = sum(1 for r in runs if r.summary.get("cut_short"))
    console.print(f"[dim]{len(runs)} run(s) read{f', {cut} cut short' if cut else ''}[/]", highlight=False)


def parse_keys(text: str) -> list[str]:
    """`--by lidar_sectors,prompt` → validated condition keys."""
    from llmnav.metrics import CONDITION_KEYS

    keys = [k.strip().replace("-", "_") for k in text.split(",") if k.strip()]
    unknown = [k for k in keys if k not in CONDITION_KEYS]
    if unknown:
        raise BadInputError(f"--by: unknown key '{unknown[0]}' (one of: {', '.join(CONDITION_KEYS)})")
    return keys


def emit(tables: list[Table], fmt: OutputFormat, out: Path | None) -> None:
    """Print the tables in the chosen format, or write them to `out`."""
    from llmnav.reporting.tables import print_tables, render_text

    if fmt is OutputFormat.rich and out is None:
        print_tables(console, tables)
        return
    text = render_text(tables, "md" if fmt is OutputFormat.rich else fmt.value)  # type: ignore[arg-type]
    if out is None:
        console.print(text, markup=False, highlight=False, soft_wrap=True, end="")
        return
    try:
        out.write_text(text, encoding="utf-8")
    except OSError as err:
        raise BadInputError(f"--out {out}: cannot write: {err.strerror or err}") from None
    console.print(f"[dim]tables written to {esc(out)}[/]")
