"""Planners: each turns observations into motion through the guard; one file a planner."""

DEFAULT_PLANNER = "hybrid"  # what `llmnav drive` runs without --planner (here, so the CLI starts without pydantic)
