"""The one way text from outside llmnav (a user's file, a model, a server, a path) reaches a Rich console."""

from __future__ import annotations

from rich.markup import escape

from llmnav.errors import printable


def esc(value: object) -> str:
    """`value` as text safe to print through Rich.

    Control characters are made visible (a task text cannot retitle or clear the terminal) and markup is
    escaped (a `[/]` in a path cannot crash or vanish).
    """
    return escape(printable(str(value)))
