"""`llmnav backends`: every registered model backend and whether it could run now."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated

import typer
from rich.table import Table

from llmnav.commands.common import cli_errors, console, esc

GROUP = "llmnav.backends"


@dataclass(frozen=True)
class BackendRow:
    """One line of the table."""

    name: str
    description: str
    example: str
    ready: bool | None  # None: the backend could not even be loaded
    detail: str


def _first_line(err: BaseException) -> str:
    text = str(err).strip().splitlines()
    return f"{type(err).__name__}: {text[0]}" if text else type(err).__name__


def collect_rows() -> list[BackendRow]:
    """Load each entry point on its own, so one broken backend shows as broken instead of hiding the rest."""
    from importlib.metadata import entry_points

    rows: list[BackendRow] = []
    for ep in sorted(entry_points(group=GROUP), key=lambda e: e.name):
        try:
            cls = ep.load()
        except Exception as err:  # noqa: BLE001 - any import failure is reported, not raised
            rows.append(BackendRow(ep.name, "", ep.name, None, f"cannot load {ep.value}: {_first_line(err)}"))
            continue
        default_arg = getattr(cls, "default_arg", None)
        example = getattr(cls, "example", "") or (f"{ep.name}:{default_arg}" if default_arg else ep.name)
        try:
            status = cls.status(default_arg)
            ready, detail = bool(status.ready), status.detail
        except Exception as err:  # noqa: BLE001 - a failing probe is a status, not a crash
            ready, detail = False, f"status check failed: {_first_line(err)}"
        rows.append(BackendRow(ep.name, getattr(cls, "description", ""), example, ready, detail))
    return rows


@cli_errors
def backends(
    check: Annotated[
        str | None,
        typer.Option(
            "--check",
            metavar="SPEC",
            help="Probe exactly this backend spec: server reachable, model present, images, JSON Schema.",
        ),
    ] = None,
) -> None:
    """List the model backends, a spec example for each, and whether each is ready to use now."""
    if check is not None:
        raise typer.Exit(_check(check))
    table = Table(title="llmnav backends", title_justify="left")
    table.add_column("name", style="bold")
    table.add_column("ready")
    table.add_column("spec example", style="cyan", no_wrap=True)
    table.add_column("detail")
    table.add_column("description", style="dim")
    for row in collect_rows():
        mark = {True: "[green]yes[/]", False: "[yellow]no[/]", None: "[red]broken[/]"}[row.ready]
        # esc, not rich's escape alone: a detail may quote a server (model names with ESC sequences)
        table.add_row(esc(row.name), mark, esc(row.example), esc(row.detail), esc(row.description))
    console.print(table)


def _check(spec: str) -> int:
    """Print one line per check of `spec`; 0 when all passed, 1 otherwise (unknown spec: exit 2)."""
    from llmnav.backends.base import backend_class

    cls, arg = backend_class(spec)
    checks = cls.check(arg)
    for item in checks:
        mark = {True: "[green]ok[/]  ", False: "[red]no[/]  ", None: "[dim]–[/]   "}[item.ok]
        console.print(f"{mark}{esc(item.name)}: {esc(item.detail)}", highlight=False, soft_wrap=True)
    return 0 if all(item.ok is not False for item in checks) else 1
