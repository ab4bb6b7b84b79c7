"""Rendering `llmnav.score.Table`s: rich tables for the terminal, Markdown, CSV and JSON."""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Sequence
from typing import TYPE_CHECKING, Literal

from llmnav.reporting.safe import esc

if TYPE_CHECKING:
    from rich.console import Console
    from rich.table import Table as RichTable

    from llmnav.score import Table

Format = Literal["rich", "md", "csv", "json"]


def to_rich(table: Table) -> RichTable:
    """A rich table (first two columns left-aligned labels, numbers right-aligned)."""
    from rich.table import Table as RichTable

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


PIPE_WIDTH = 240  # [characters] width of tables written to a pipe or file: never squeezed to 80 columns


def print_tables(console: Console, tables: Sequence[Table]) -> None:
    """Print rich tables: fitted to a terminal, at their natural width when piped."""
    if console.is_terminal:
        for table in tables:
            console.print(to_rich(table))
        return
    previous = console.width  # print(width=...) is capped at the console's width: widen it for a moment
    console.width = max(previous, PIPE_WIDTH)
    try:
        for table in tables:
            console.print(to_rich(table))
    finally:
        console.width = previous


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


def to_csv(tables: Sequence[Table]) -> str:
    """One CSV: a `table` column naming the table, then that table's columns (header repeated per table)."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    for table in tables:
        writer.writerow(["table", *table.columns])
        for row in table.rows:
            writer.writerow([table.title, *row])
    return buffer.getvalue()


def to_json(tables: Sequence[Table]) -> str:
    """The tables' raw records (numbers, not formatted strings)."""
    data = [{"title": t.title, "note": t.note, "records": t.records} for t in tables]
    return json.dumps(data, indent=2, allow_nan=False, default=str) + "\n"


def render_text(tables: Sequence[Table], fmt: Format) -> str:
    """Markdown, CSV or JSON text of the tables (`rich` renders through a console instead)."""
    if fmt == "md":
        return to_markdown(tables)
    if fmt == "csv":
        return to_csv(tables)
    if fmt == "json":
        return to_json(tables)
    raise ValueError(f"no text rendering for format {fmt!r}")
