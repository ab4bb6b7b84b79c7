"""The `llmnav` command line: each command lives in `llmnav/commands/` and only parses arguments."""

from __future__ import annotations

import importlib

import typer

app = typer.Typer(
    name="llmnav",
    help="Drive a simulated mobile robot with large language models, safely and measurably.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode="rich",
)

# (command name, module in llmnav.commands, function): one line per command keeps this file a table of contents.
_COMMANDS: list[tuple[str, str, str]] = [
    ("drive", "drive", "drive"),
    ("plan", "plan", "plan"),
    ("score", "score", "score"),
    ("ablate", "ablate", "ablate"),
    ("backends", "backends", "backends"),
    ("transcribe", "transcribe", "transcribe"),
]
_GROUPS: list[tuple[str, str]] = [("scenarios", "scenarios")]

for _name, _module, _func in _COMMANDS:
    try:
        _mod = importlib.import_module(f"llmnav.commands.{_module}")
    except ModuleNotFoundError as _err:  # a command still being built must not break the others
        if _err.name != f"llmnav.commands.{_module}":
            raise
        continue
    app.command(_name)(getattr(_mod, _func))

for _name, _module in _GROUPS:
    try:
        _mod = importlib.import_module(f"llmnav.commands.{_module}")
    except ModuleNotFoundError as _err:
        if _err.name != f"llmnav.commands.{_module}":
            raise
        continue
    app.add_typer(_mod.app, name=_name)


def main() -> None:
    """Console-script entry point."""
    app()
