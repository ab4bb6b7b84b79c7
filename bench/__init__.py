"""llmnav's benchmarks: one module a subject, each with `main(quick: bool = False)` that prints its table.

Quick mode runs the same functions with a few iterations (seconds a module), so the default test suite can
run every benchmark and a change that breaks one fails there; its numbers measure nothing and no target is
judged on them. `python -m bench --quick` (or `LLMNAV_BENCH_QUICK=1`) asks for it.
"""

from __future__ import annotations

import os

QUICK_ENV = "LLMNAV_BENCH_QUICK"
NOT_MEASURED = "quick: not a measurement"


def quick_from_env() -> bool:
    """Whether `LLMNAV_BENCH_QUICK` asks for quick mode (1, true or yes)."""
    return os.environ.get(QUICK_ENV, "").strip().lower() in ("1", "true", "yes")


def judged(verdict: str, quick: bool) -> str:
    """A verdict against a target, or in quick mode the note that a few iterations judge nothing."""
    return NOT_MEASURED if quick else verdict
