"""The hybrid planner: a model chooses among a few options; A* and the motion layer carry the choice out.

`planner` is the decide-execute loop; `menu` builds the options, `prompt` asks for the choice, `scoring`
is the decision by scored option texts (how a small model chooses well), `execute` carries the choice
out through the shared leg driver, `memory` keeps the landmarks.
"""

from llmnav.planners.hybrid.config import HybridConfig
from llmnav.planners.hybrid.planner import HybridPlanner

__all__ = ["HybridConfig", "HybridPlanner"]
