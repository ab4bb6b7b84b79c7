"""Printing tables to a pipe: at their natural width, however wide, and the console follows COLUMNS afterwards."""

from __future__ import annotations

import io

from rich.console import Console

from llmnav.reporting.tables import print_tables
from llmnav.scoring.score import Table

WIDE = 500  # [characters] a cell wider than any terminal default (the old pipe width was 240)


def test_printing_to_a_pipe_does_not_pin_the_console_width(monkeypatch) -> None:  # noqa: ANN001
    monkeypatch.delenv("COLUMNS", raising=False)
    out = io.StringIO()
    console = Console(file=out, force_terminal=False)  # as llmnav's: created before COLUMNS is set
    monkeypatch.setenv("COLUMNS", "80")
    print_tables(console, [Table(title="t", columns=["a"], rows=[["x" * WIDE]])])
    assert "x" * WIDE in out.getvalue() and "…" not in out.getvalue()  # one line, never cut
    monkeypatch.setenv("COLUMNS", "300")
    assert console.width == 300  # it was pinned at the 80 it had before printing
