"""The named flags of single planners, built for `drive` and `ablate` in one place.

A planner declares them on its options model (`DriveOptions.cli_flags`, a tuple of `CliFlag`), so no command
names a planner or its keys, and a plug-in planner adds a flag by declaring one. Typer reads a command's
flags from its function signature, which cannot grow after import; so a command that takes planner flags
is built with `cls=DriveFlags` or `cls=SweepFlags` (the command function sets `command_class`), a Typer
command whose parameter list appends the planners' flags the first time it is parsed or its help is
shown. Only then are the planners imported: `llmnav --help` and the other commands do not pay for it.

The flags are made by Typer itself (a throwaway command built from a synthetic signature), so they parse,
print and fail exactly like the flags written out in a signature. The values given reach the command in
`ctx.meta[GIVEN]`, a mapping of option key → value (absent when not given).

The first declaration of a flag wins (planners in name order, llmnav's own among them); a later one of the
same flag, or one spelling a flag the command already has, is left out, and its key stays reachable as
`-o KEY=VALUE`.
"""

from __future__ import annotations

import inspect
from typing import TYPE_CHECKING, Annotated, Any, ClassVar

import typer
from typer.core import TyperCommand

if TYPE_CHECKING:
    from llmnav.planners.options import CliFlag

GIVEN = "llmnav.planner_flags"  # ctx.meta key: {option key: value given by its flag}
_PREFIX = "planner_flag_"


def declared_flags(*, sweep: bool) -> list[CliFlag]:
    """The flags the installed planners declare (for `ablate` only those with a `sweep`), one per spelling."""
    # deferred: the planner registry brings pydantic (about 0.1 s), not for `llmnav --help`
    from llmnav.planners.base import planner_class, usable_planner_names

    found: dict[str, CliFlag] = {}
    for name in usable_planner_names():
        for flag in planner_class(name).Options.cli_flags:
            if (flag.sweep is not None or not sweep) and flag.flag not in found:
                found[flag.flag] = flag
    return list(found.values())


def flag_of(key: str) -> str | None:
    """The planner flag that sets option field `key` (its own key, or one in its `also`), None when none does."""
    for flag in declared_flags(sweep=False):
        if key == flag.key or key in flag.also:
            return flag.flag
    return None


def _parameter(flag: CliFlag, sweep: bool) -> inspect.Parameter:
    name = _PREFIX + flag.key
    if flag.switch and not sweep:
        annotation: Any = Annotated[bool, typer.Option(flag.flag, help=flag.help)]
        return inspect.Parameter(name, inspect.Parameter.KEYWORD_ONLY, default=False, annotation=annotation)
    text = (flag.sweep_help or flag.help) if sweep else flag.help
    annotation = Annotated[str | None, typer.Option(flag.flag, help=text)]
    return inspect.Parameter(name, inspect.Parameter.KEYWORD_ONLY, default=None, annotation=annotation)


def _click_params(flags: list[CliFlag], sweep: bool) -> list[Any]:
    """Typer's own parameters for `flags`: a command built from a synthetic signature, then taken apart."""

    def holder(**_: Any) -> None:
        """Never run: only its signature is read."""

    parameters = [_parameter(flag, sweep) for flag in flags]
    holder.__signature__ = inspect.Signature(parameters)  # type: ignore[attr-defined]
    holder.__annotations__ = {p.name: p.annotation for p in parameters}
    scratch = typer.Typer()
    scratch.command()(holder)
    scratch.command("unused")(holder)  # two commands: get_command returns a group whose commands we read
    group: Any = typer.main.get_command(scratch)
    return list(group.commands[holder.__name__].params)


class DriveFlags(TyperCommand):
    """A Typer command that also takes the flags the installed planners declare (one value each)."""

    sweep: ClassVar[bool] = False
    _planner_params: list[tuple[CliFlag, Any]] | None = None

    def _planner_flags(self) -> list[tuple[CliFlag, Any]]:
        if self._planner_params is None:
            taken = {opt for param in self.params for opt in getattr(param, "opts", ())}
            flags = [f for f in declared_flags(sweep=self.sweep) if f.flag not in taken]
            self._planner_params = list(zip(flags, _click_params(flags, self.sweep), strict=True))
        return self._planner_params

    def get_params(self, ctx: Any) -> list[Any]:
        """The command's own parameters, then the planners' flags, then --help."""
        help_option = self.get_help_option(ctx)
        extra = [param for _, param in self._planner_flags()]
        return [*self.params, *extra, *([help_option] if help_option is not None else [])]

    def invoke(self, ctx: Any) -> Any:
        """Move the planner flags' values out of the call into `ctx.meta[GIVEN]`."""
        given: dict[str, Any] = {}
        for flag, param in self._planner_flags():
            value = ctx.params.pop(param.name, None)
            if value is not None and value is not False:
                given[flag.key] = value
        ctx.meta[GIVEN] = given
        return super().invoke(ctx)


class SweepFlags(DriveFlags):
    """`ablate`'s: only the flags declaring a `sweep`, each taking a comma-separated list or one value."""

    sweep: ClassVar[bool] = True
