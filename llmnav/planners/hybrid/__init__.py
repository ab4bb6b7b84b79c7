"""The hybrid planner: a model chooses among a few options; A* and the motion layer carry the choice out.

`planner` builds the menu, asks or scores, and executes; `scoring` is the decision by scored option
texts (how a small model chooses well).
"""

from llmnav.planners.hybrid.planner import HybridConfig, HybridPlanner

__all__ = ["HybridConfig", "HybridPlanner"]
