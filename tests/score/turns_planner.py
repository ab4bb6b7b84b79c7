"""A third-party planner for the score tests: it turns in place and declares a table over its own metric.

Registered for a test through an entry point in a temporary dist-info (see test_declared_tables.py);
nothing in llmnav knows it.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

from llmnav.core.declarations import Column, Declarations, ScoreTable
from llmnav.planners.base import EpisodeContext, EpisodeOutcome, Planner

TURNS_TABLE = ScoreTable(
    name="turns",
    title="Turning planner (its own table)",
    columns=(
        Column("turns", "Turns", digits=1),
        Column("dizzy", "Dizzy", aggregate="rate"),
        Column("wobble_deg", "Wobble (deg)", path="wobble.mean", digits=3),
    ),
    note="declared by the planner, not by llmnav",
)


class TurnsPlanner(Planner):
    """Turns a quarter circle per iteration and counts the turns."""

    name: ClassVar[str] = "turns"
    needs_backend: ClassVar[bool] = False
    declares: ClassVar[Declarations] = Declarations(score_tables=(TURNS_TABLE,), decision_noun="Turn")

    def run(self, ctx: EpisodeContext) -> EpisodeOutcome:
        """Turn `max_iterations` times."""
        for _ in range(ctx.options.max_iterations):
            ctx.world.motion.rotate(math.pi / 2)
        turns = ctx.options.max_iterations
        metrics: dict[str, Any] = {"turns": turns, "dizzy": turns > 3}
        return EpisodeOutcome("completed", "turned", turns, metrics)
