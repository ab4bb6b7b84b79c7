"""Locate bundled data folders (prompts/, scenarios/) in a wheel install or a source checkout."""

from __future__ import annotations

from pathlib import Path

_PACKAGE = Path(__file__).resolve().parent.parent  # the llmnav package (this module lives in core/)


def resource_dir(name: str) -> Path:
    """The bundled folder `name`: `llmnav/_data/NAME` in a wheel, `./NAME` at the repo root otherwise."""
    for candidate in (_PACKAGE / "_data" / name, _PACKAGE.parent / name):
        if candidate.is_dir():
            return candidate
    raise FileNotFoundError(f"llmnav's bundled folder '{name}' is missing; reinstall llmnav")
