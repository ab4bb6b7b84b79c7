"""`llmnav planners`: the registered planners, what each may know, and the options `-o KEY=VALUE` sets."""

from __future__ import annotations

import json
from typing import Annotated, Any

import typer
from rich.table import Table

from llmnav.commands.common import cli_errors, esc, listing_format, print_data, print_listing, print_table
from llmnav.errors import one_line


def _default(value: Any) -> str:
    if isinstance(value, tuple):
        return "+".join(map(str, value)) or "()"
    return str(value)


def describe(name: str) -> dict[str, Any]:
    """One planner's declarations: information modes, ablation factors, and every option with its default."""
    # deferred: the planner registry brings pydantic (about 0.1 s), not for `llmnav --help`
    from llmnav.planners.base import DriveOptions, planner_class

    cls = planner_class(name)
    own = set(cls.Options.model_fields) - set(DriveOptions.model_fields)
    options = [
        {
            "key": key,
            "default": _default(field.default),
            "description": field.description or "",
            "own": key in own,
        }
        for key, field in cls.Options.model_fields.items()
        if key != "planner"
    ]
    return {
        "planner": name,
        "model": cls.needs_backend,
        "information": list(cls.information_modes),
        "grid_factors": list(cls.grid_factors),
        "oracle_answers": cls.offers_oracle_answers(),
        "options": options,
    }


@cli_errors
def planners(
    name: Annotated[str | None, typer.Argument(help="Show this planner's options (default: list all).")] = None,
    output_format: Annotated[
        str, typer.Option("--format", help="table | tsv | json (tsv and json: only data on stdout).")
    ] = "table",
) -> None:
    """List the registered planners, or one planner's options (what `drive -o KEY=VALUE` may set).

    A planner plugin that cannot be used (it fails to import, is not a Planner, or shares its name with
    another distribution's) is listed as broken with its reason; the others are listed as usual.
    """
    # deferred: the planner registry brings pydantic (about 0.1 s), not for `llmnav --help`
    from llmnav.planners.base import broken_planners, usable_planner_names

    output_format = listing_format(output_format)
    described = [describe(n) for n in ([name] if name else usable_planner_names())]
    broken = broken_planners() if name is None else {}
    if output_format == "json":
        rows = described + [{"planner": n, "broken": reason} for n, reason in broken.items()]
        print_data(json.dumps(rows if name is None else described[0]))
        return
    if output_format == "tsv":
        print_listing("tsv", _tsv_records(described, broken, listing=name is None), None)
        return
    if name is None:
        table = Table(title="Registered planners (llmnav.planners entry points)")
        for column in ("planner", "information", "own options", "oracle answers"):
            table.add_column(column)
        for d in described:
            own = ", ".join(o["key"] for o in d["options"] if o["own"]) or "-"
            oracle = "yes" if d["oracle_answers"] else "no"
            table.add_row(esc(d["planner"]), ", ".join(d["information"]), esc(own), oracle)
        for planner, reason in broken.items():
            table.add_row(esc(planner), "[red]broken[/]", esc(one_line(reason, 200)), "-")
        print_table(table)
        return
    d = described[0]
    table = Table(title=esc(f"{d['planner']}: options (-o KEY=VALUE); information: {', '.join(d['information'])}"))
    for column in ("key", "default", "description [unit]"):
        table.add_column(column)
    for o in sorted(d["options"], key=lambda o: (not o["own"], o["key"])):
        table.add_row(esc(o["key"]) + ("" if o["own"] else " (shared)"), esc(o["default"]), esc(o["description"]))
    print_table(table)


def _tsv_records(described: list[dict[str, Any]], broken: dict[str, str], *, listing: bool) -> list[dict[str, Any]]:
    """A line per planner (the listing), or a line per option of the one planner asked for."""
    if not listing:
        return [{"planner": described[0]["planner"], **option} for option in described[0]["options"]]
    rows: list[dict[str, Any]] = [
        {
            "planner": d["planner"],
            "model": d["model"],
            "information": d["information"],
            "own_options": [o["key"] for o in d["options"] if o["own"]],
            "oracle_answers": d["oracle_answers"],
            "broken": "",
        }
        for d in described
    ]
    return rows + [{"planner": planner, "broken": one_line(reason, 200)} for planner, reason in broken.items()]
