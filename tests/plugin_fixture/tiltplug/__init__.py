"""A third-party llmnav planner: asks the model how far to turn towards the target, then turns."""

from tiltplug.planner import TiltOptions, TiltPlanner

__all__ = ["TiltOptions", "TiltPlanner"]
