"""The `llmnav` command line: each command lives in `llmnav/commands/` and only parses arguments."""

from __future__ import annotations

import importlib
import logging
import sys
from collections.abc import Callable

import typer

from llmnav.commands.common import err_console, esc, fail
from llmnav.core import plugins
from llmnav.errors import printable

# (command name, module in llmnav.commands, function): one line per command keeps this file a table of contents.
_COMMANDS: list[tuple[str, str, str]] = [
    ("drive", "drive", "drive"),
    ("plan", "plan", "plan"),  # also registered under llmnav.commands by the waypoint planner's entry point
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
# The entry-point group where installed distributions add commands: NAME = "module:function-or-typer.Typer"
COMMAND_GROUP = "llmnav.commands"


def _builtin_commands() -> dict[str, tuple[str, object]]:
    """Each built-in command's name → (its "module:attribute", the function or Typer app)."""
    found: dict[str, tuple[str, object]] = {}
    for name, module, attribute in [*_COMMANDS, *((name, module, "app") for name, module in _GROUPS)]:
        try:
            mod = importlib.import_module(f"llmnav.commands.{module}")
        except ModuleNotFoundError as err:  # a command still being built must not break the others
            if err.name != f"llmnav.commands.{module}":
                raise
            continue
        found[name] = (f"llmnav.commands.{module}:{attribute}", getattr(mod, attribute))
    return found


def _not_a_command(target: object) -> str | None:
    """Why an entry point's target cannot be a command (None when it can)."""
    if isinstance(target, typer.Typer) or callable(target):
        return None
    return f"is not a command: {type(target).__name__} (register a function or a typer.Typer)"


def plugin_commands(builtins: dict[str, str]) -> tuple[dict[str, object], dict[str, str]]:
    """The commands installed distributions register under `llmnav.commands`, and the refused ones.

    `builtins` maps each built-in name to its "module:attribute". A registration of a built-in's own
    target (llmnav's entry point for `plan`) is that built-in, not a clash. Returns (name → function or
    Typer app, name → one-line problem): a clash with a built-in or another distribution, or a target that
    fails to load, is refused there and troubles no other command.
    """
    commands: dict[str, object] = {}
    problems: dict[str, str] = {}
    for name, registered in sorted(plugins.registrations(COMMAND_GROUP).items()):
        others = tuple(p for p in registered if p.value != builtins.get(name))
        if not others:
            continue  # llmnav's own registration of a built-in
        if name in builtins:
            who = " and ".join(f"{p.source} ({p.value})" for p in others)
            problems[name] = (
                f"command '{name}' of {who} clashes with the built-in command '{name}' ({builtins[name]}): "
                "the built-in is kept (a plugin never replaces a command silently)"
            )
            continue
        try:
            commands[name] = plugins.load(COMMAND_GROUP, "command", name, _not_a_command)
        except Exception as err:  # noqa: BLE001 - BadInputError from plugins, one line
            problems[name] = str(err)
    return commands, problems


def make_app() -> typer.Typer:
    """The `llmnav` app: the built-in commands, then those of installed plugins (refused ones listed)."""
    app = typer.Typer(
        name="llmnav",
        help="Drive a simulated mobile robot with large language models, safely and measurably.",
        no_args_is_help=True,
        add_completion=False,
        pretty_exceptions_enable=False,
        rich_markup_mode="rich",
    )
    builtins = _builtin_commands()
    extra, problems = plugin_commands({name: value for name, (value, _) in builtins.items()})
    for name, (_, target) in [*builtins.items(), *((n, ("", t)) for n, t in extra.items())]:
        if isinstance(target, typer.Typer):
            app.add_typer(target, name=name)
        else:
            # a command taking the planners' flags names its Typer command class (llmnav.commands.planner_flags)
            app.command(name, cls=getattr(target, "command_class", None))(target)  # type: ignore[type-var]
    for name, problem in problems.items():
        if name not in builtins:  # a broken plugin's name still answers, with its one-line problem
            app.command(name, help=f"[red]broken[/]: {problem}", add_help_option=False)(_refuse(problem))
    if problems:
        app.info.epilog = "Refused plugin commands: " + "; ".join(problems.values())
    return app


def _refuse(problem: str) -> Callable[[], None]:
    def refused() -> None:
        raise fail(problem)

    return refused


app = make_app()


def _usage_errors() -> tuple[type[Exception], ...]:
    """Click's exception base: typer >= 0.25 vendors its own click, older versions use click itself."""
    kinds: list[type[Exception]] = []
    try:
        # optional: older typer versions may lack typer.exceptions (see the docstring)
        from typer.exceptions import TyperException

        kinds.append(TyperException)
    except ImportError:
        pass
    try:
        # deferred: click (about 0.03 s) loads only when a command fails, and may not be installed
        import click

        kinds.append(click.ClickException)
    except ImportError:
        pass
    return tuple(kinds)


def _show_retries() -> None:
    """Llmnav's INFO log lines (each retry of a model server) as one printable line each on stderr.

    A hanging server can take minutes over its retries; even under --quiet the user sees why.
    """

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
