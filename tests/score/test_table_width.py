"""Printing tables to a pipe widens the console for a moment and leaves it following COLUMNS afterwards."""

from __future__ import annotations

import io

from rich.console import Console

from llmnav.reporting.tables import PIPE_WIDTH, print_tables
from llmnav.score import Table


def test_printing_to_a_pipe_does_not_pin_the_console_width(monkeypatch) -> None:  # noqa: ANN001
    monkeypatch.delenv("COLUMNS", raising=False)
    console = Console(file=io.StringIO(), force_terminal=False)  # as llmnav's: created before COLUMNS is set
    monkeypatch.setenv("COLUMNS", "80")
    print_tables(console, [Table(title="t", columns=["a"], rows=[["x" * (PIPE_WIDTH - 20)]])])
    monkeypatch.setenv("COLUMNS", "300")
    assert console.width == 300  # it was pinned at the 80 it had before printing
