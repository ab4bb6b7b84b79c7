"""Stepwise multimodal planner (source A): `planner` runs the guarded loop, `oracle` answers it from ground truth."""

from llmnav.planners.stepwise.planner import StepwisePlanner, describe_action, history_window

__all__ = ["StepwisePlanner", "describe_action", "history_window"]
