"""`llmnav backends`: every registered model backend and whether it could run now."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated

import typer
from rich.table import Table

from llmnav.commands.common import cli_errors, console, esc, listing_format, parse_sensing, print_listing
from llmnav.core import plugins
from llmnav.errors import BadInputError

GROUP = "llmnav.backends"
SENSES = ("lidar", "image", "detections")


@dataclass(frozen=True)
class BackendRow:
    """One line of the table."""

    name: str
    description: str
    example: str
    ready: bool | None  # None: the backend could not even be loaded
    detail: str

    def record(self) -> dict[str, str | bool | None]:
        """The row as data (`--format json|tsv`); `ready` is null for a backend that could not be loaded."""
        return {
            "name": self.name,
            "ready": self.ready,
            "broken": self.ready is None,
            "spec_example": self.example,
            "detail": self.detail,
            "description": self.description,
        }


def _first_line(err: BaseException) -> str:
    text = str(err).strip().splitlines()
    return f"{type(err).__name__}: {text[0]}" if text else type(err).__name__


def collect_rows() -> list[BackendRow]:
    """Load each entry point on its own, so one broken backend shows as broken instead of hiding the rest.

    A name two distributions register is shown as broken too, naming both (neither is used).
    """
    rows: list[BackendRow] = []
    for name, registered in sorted(plugins.registrations(GROUP).items()):
        if len(registered) > 1:
            rows.append(BackendRow(name, "", name, None, plugins.clash_message("backend", name, registered)))
            continue
        ep = registered[0].entry_point
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
        for arg, description in (getattr(cls, "variants", None) or {}).items():
            try:
                status = cls.status(arg)
                ready, detail = bool(status.ready), status.detail
            except Exception as err:  # noqa: BLE001
                ready, detail = False, f"status check failed: {_first_line(err)}"
            rows.append(BackendRow(ep.name, description, f"{ep.name}:{arg}", ready, detail))
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
    sensing: Annotated[
        str | None,
        typer.Option(
            "--sensing",
            help="With --check: judge only what a run with this sensing needs (lidar alone needs no images).",
        ),
    ] = None,
    output_format: Annotated[
        str, typer.Option("--format", help="table | tsv | json (tsv and json: only data on stdout).")
    ] = "table",
) -> None:
    """List the model backends, a spec example for each, and whether each is ready to use now."""
    output_format = listing_format(output_format)
    senses = _senses(sensing) if sensing is not None else None
    if check is not None:
        raise typer.Exit(_check(check, senses, output_format))
    if senses is not None:
        raise BadInputError("--sensing goes with --check SPEC")
    table = Table(title="llmnav backends", title_justify="left")
    table.add_column("name", style="bold", no_wrap=True)
    table.add_column("ready")
    table.add_column("spec example", style="cyan", no_wrap=True)
    table.add_column("detail")
    table.add_column("description", style="dim")
    rows = collect_rows()
    for row in rows:
        mark = {True: "[green]yes[/]", False: "[yellow]no[/]", None: "[red]broken[/]"}[row.ready]
        # esc, not rich's escape alone: a detail may quote a server (model names with ESC sequences)
        table.add_row(esc(row.name), mark, esc(row.example), esc(row.detail), esc(row.description))
    print_listing(output_format, [row.record() for row in rows], table)


def _senses(text: str) -> tuple[str, ...]:
    senses = parse_sensing(text)
    unknown = [s for s in senses if s not in SENSES]
    if unknown or not senses:
        raise BadInputError(f"--sensing {text!r}: a comma list of {', '.join(SENSES)}")
    return senses


def _check(spec: str, senses: tuple[str, ...] | None = None, output_format: str = "table") -> int:
    """Print one line per check of `spec`; 0 when all passed, 1 otherwise (unknown spec: exit 2).

    With `senses`, a check the run does not need (images, when the sensing has no image) is shown with
    its result but marked "not needed" and does not fail. `json`/`tsv`: one record per check, `ok` null
    for one not needed.
    """
    # deferred: the HTTP backends bring pydantic (about 0.1 s), only with --check
    from llmnav.backends.base import Check, backend_class
    from llmnav.backends.http import IMAGES_CHECK

    cls, arg = backend_class(spec)
    cls.check_arg(arg)  # an argument no run could use (`openai:m@http://`) is bad input, not a failed check
    checks = cls.check(arg)
    if senses is not None and "image" not in senses:
        checks = [
            Check(c.name, None, f"{c.detail} — not needed with --sensing {','.join(senses)}")
            if c.name == IMAGES_CHECK and c.ok is False
            else c
            for c in checks
        ]
    passed = 0 if all(item.ok is not False for item in checks) else 1
    if output_format != "table":
        records = [{"check": item.name, "ok": item.ok, "detail": item.detail} for item in checks]
        print_listing(output_format, records, None)
        return passed
    for item in checks:
        mark = {True: "[green]ok[/]  ", False: "[red]no[/]  ", None: "[dim]–[/]   "}[item.ok]
        console.print(f"{mark}{esc(item.name)}: {esc(item.detail)}", highlight=False, soft_wrap=True)
    return passed
