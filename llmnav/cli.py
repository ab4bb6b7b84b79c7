"""The `llmnav` command line: each command lives in `llmnav/commands/` and only parses arguments."""

from __future__ import annotations

import importlib
import sys

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
    ("planners", "planners", "planners"),
    ("transcribe", "transcribe", "transcribe"),
    ("view", "view", "view"),
    ("serve", "serve", "serve"),
    ("export", "export", "export"),
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


def _usage_errors() -> tuple[type[Exception], ...]:
    """Click's exception base: typer >= 0.25 vendors its own click, older versions use click itself."""
    kinds: list[type[Exception]] = []
    try:
        from typer.exceptions import TyperException

        kinds.append(TyperException)
    except ImportError:
        pass
    try:
        import click

        kinds.append(click.ClickException)
    except ImportError:
        pass
    return tuple(kinds)


def _show_retries() -> None:
    """Llmnav's INFO log lines (each retry of a model server) as one printable line each on stderr.

    A hanging server can take minutes over its retries; even under --quiet the user sees why.
    """
    import logging

    from llmnav.errors import printable

    class OneLine(logging.Formatter):
        def format(self, record: logging.LogRecord) -> str:
            return "llmnav: " + printable(" ".join(super().format(record).split()))

    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(OneLine("%(message)s"))
    logger = logging.getLogger("llmnav")
    logger.addHandler(handler)
    logger.setLevel(logging.INFO)
    logger.propagate = False


def main() -> None:
    """Console-script entry point: usage errors (bad flags or values) become one line and exit 2."""
    from llmnav.commands.common import err_console, esc

    _show_retries()

    try:
        result = app(standalone_mode=False)
    except typer.Abort:
        err_console.print("[bold red]error:[/] interrupted; everything written so far is kept")
        raise SystemExit(130) from None
    except _usage_errors() as err:
        format_message = getattr(err, "format_message", None)
        message = " ".join((format_message() if format_message else str(err)).split())
        ctx = getattr(err, "ctx", None)
        where = ctx.command_path if ctx is not None else "llmnav"
        err_console.print(
            f"[bold red]error:[/] {esc(message)} (see '{esc(where)} --help')", highlight=False, soft_wrap=True
        )
        raise SystemExit(getattr(err, "exit_code", 2)) from None
    raise SystemExit(result if isinstance(result, int) else 0)
