"""Planners: each turns observations into motion through the guard; one file a planner."""
