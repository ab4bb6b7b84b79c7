"""Rendering `llmnav.scoring.score.Table`s: rich tables for the terminal, Markdown, tidy CSV (one table) and JSON."""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, Literal

from rich.measure import Measurement
from rich.table import Table as RichTable

from llmnav.reporting.safe import esc

if TYPE_CHECKING:
    from rich.console import Console

    from llmnav.scoring.score import Table

Format = Literal["rich", "md", "csv", "json"]


def to_rich(table: Table) -> RichTable:
    """A rich table (first two columns left-aligned labels, numbers right-aligned)."""
    out = RichTable(
        title=esc(table.title) if table.title else None,
        caption=esc(table.note) if table.note else None,
        title_justify="left",
        header_style="bold",
    )
    for i, column in enumerate(table.columns):
        if i < 2:  # labels keep their width (capped) in a narrow terminal; numbers wrap instead
            width = max([len(column), *(len(row[i]) for row in table.rows)])
            out.add_column(esc(column), justify="left", no_wrap=True, min_width=min(width, 36))
        else:
            out.add_column(esc(column), justify="right", overflow="fold")
    for row in table.rows:  # labels quote backends, paths and task ids: never markup
        out.add_row(*(esc(cell) for cell in row))
    return out


UNBOUNDED = 1 << 16  # [characters] a width no table reaches: measure at this to get its natural width


def print_unsqueezed(console: Console, renderable: Any) -> None:
    """Print fitted to a terminal; to a pipe or file at its natural width, however wide.

    Rich fits output to 80 columns when it is not writing to a terminal, which cuts table cells with
    ellipses ("policy:ora…") and wraps the rest: `llmnav backends | grep oracle` found nothing. Piped,
    a table is as wide as its longest cells need, one line per row.
    """
    if console.is_terminal:
        console.print(renderable)
        return

    natural = Measurement.get(console, console.options.update_width(UNBOUNDED), renderable).maximum
    # print(width=...) is capped at the console's width: widen it for a moment. Restore the setting itself
    # (None: follow COLUMNS and the terminal), not the width it gave then, which would pin it for good.
    previous = console._width
    console.width = max(console.width, natural)
    try:
        console.print(renderable)
    finally:
        console._width = previous


def print_tables(console: Console, tables: Sequence[Table]) -> None:
    """Print rich tables: fitted to a terminal, at their natural width when piped."""
    for table in tables:
        print_unsqueezed(console, to_rich(table))


def _md_cell(text: str) -> str:
    return text.replace("|", "\\|")


def to_markdown(tables: Sequence[Table]) -> str:
    """GitHub-flavoured Markdown: a heading and a pipe table per table."""
    parts = []
    for table in tables:
        lines = [f"### {table.title}", ""]
        lines.append("| " + " | ".join(_md_cell(c) for c in table.columns) + " |")
        lines.append("|" + "|".join("---" if i < 2 else "---:" for i in range(len(table.columns))) + "|")
        lines.extend("| " + " | ".join(_md_cell(c) for c in row) + " |" for row in table.rows)
        if table.note:
            lines += ["", f"_{table.note}_"]
        parts.append("\n".join(lines))
    return "\n\n".join(parts) + "\n"


def flatten(record: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """One level of columns from a nested record: `score: {mean, sd, ci95: [lo, hi]}` -> `score_mean`, ...

    Nested dicts join their keys with `_`; a two-item `ci95` (or `..._ci95`) becomes `_low` and `_high`;
    other lists are written as JSON text so a cell never holds a Python repr.
    """
    out: dict[str, Any] = {}
    for key, value in record.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(flatten(value, f"{name}_"))
        elif isinstance(value, list) and (key == "ci95" or key.endswith("_ci95")) and len(value) == 2:
            out[f"{name}_low"], out[f"{name}_high"] = value
        elif isinstance(value, list):
            out[name] = json.dumps(value)
        else:
            out[name] = value
    return out


def to_csv(table: Table) -> str:
    """One tidy CSV table: a row per record (task × condition), one column per metric, raw numbers.

    Columns are the union over the rows, in order of first appearance; a value a row lacks is empty. A
    column empty in every row is left out (pandas would read it as a column of NaN).
    """
    rows = [flatten(r) for r in table.records]
    columns: dict[str, None] = {}
    for row in rows:
        columns.update(dict.fromkeys(k for k, v in row.items() if v is not None and v != ""))
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=list(columns), lineterminator="\n", restval="", extrasaction="ignore")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: "" if v is None else v for k, v in row.items()})
    return buffer.getvalue()


def without_empty_fields(records: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """The records without the fields that are null in every one of them (nothing to show)."""
    filled = {k for record in records for k, v in record.items() if v is not None}
    return [{k: v for k, v in record.items() if k in filled} for record in records]


def to_json(tables: Sequence[Table]) -> str:
    """The tables' raw records (numbers, not formatted strings); a field null in every record is left out."""
    data = [
        {"name": t.name, "title": t.title, "note": t.note, "records": without_empty_fields(t.records)} for t in tables
    ]
    return json.dumps(data, indent=2, allow_nan=False, default=str) + "\n"


def render_text(tables: Sequence[Table], fmt: Format) -> str:
    """Markdown, CSV or JSON text of the tables (`rich` renders through a console instead)."""
    if fmt == "md":
        return to_markdown(tables)
    if fmt == "csv":
        if len(tables) != 1:
            raise ValueError("CSV holds one table: pick it first")
        return to_csv(tables[0])
    if fmt == "json":
        return to_json(tables)
    raise ValueError(f"no text rendering for format {fmt!r}")
