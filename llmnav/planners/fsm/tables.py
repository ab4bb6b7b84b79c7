"""What the FSM declares for the layers above it: its score table (source C, Tables 5–6) and its page.

Columns: e_pos, η, loop and model latency, acceptance and utilisation ratios, the shares of suggestions
accepted or rejected (stale, bounds, parse) pooled over a group, and the median new prompt tokens.
"""

from __future__ import annotations

from llmnav.core.declarations import Column, Declarations, ScoreTable

FSM_TABLE = ScoreTable(
    name="fsm",
    title="FSM with LLM assist (FSM source, Tables 5–6 style)",
    columns=(
        Column("e_pos_m", "e_pos (m)", digits=3, bounds=(0.0, None)),
        Column("eta", "η", digits=3, bounds=(0.0, None)),
        Column("loop_latency_ms", "Loop (ms)", path="tick_latency_ms.mean", bounds=(0.0, None)),
        Column("model_latency_ms", "Model (ms)", digits=1, path="model_latency_ms.mean", bounds=(0.0, None)),
        Column("r_acc", "r_acc", bounds=(0.0, 1.0)),
        Column("r_use", "r_use", bounds=(0.0, 1.0)),
        Column("accepted", "Accepted", aggregate="share", per="suggestions"),
        Column("stale", "Stale", aggregate="share", path="rejected.stale", per="suggestions"),
        Column("bounds", "Bounds", aggregate="share", path="rejected.bounds", per="suggestions"),
        Column("parse", "Parse", aggregate="share", path="rejected.parse", per="suggestions"),
        Column(
            "new_prompt_tokens",
            "New tok",
            aggregate="median",
            digits=0,
            source="summary",
            path="new_prompt_tokens_median",
            bounds=(0.0, None),
        ),
    ),
    marker="e_pos_m",
    note="validation outcomes: shares of all suggestions of the group; New tok: median of run medians",
)

# Velocities every tick, a model only with `--assist llm`: the page shows suggestions and the profile.
FSM_DECLARATIONS = Declarations(score_tables=(FSM_TABLE,), velocity_view=True, model_switch="assist")
