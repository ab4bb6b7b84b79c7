"""Why a run did not succeed: exactly one cause per failed run (`failure_cause` in summary.json).

A leaf module: it reads a summary's fields (and the run's last `action` event, when there is one), never the
planners, so every planner's end is classified the same way. The causes, tried in this order (the first
that holds is the cause):

- `outage`: nothing of the navigation to judge: the backend or its server failed (no answer came), a range
  sensor the collision monitor relies on failed, the run crashed, was interrupted, or was cut short (no `end` event).
- `collision`: the robot touched something during the episode (`collisions` > 0), however it ended.
- `not_found`: the planner ended without a target it could reach: the outcome `not_found` ("explored the
  reachable floor; no landmark fits"), exploration with no frontier left, a target no collision-free path
  reaches, no sign found while searching.
- `wrong_place`: the run completed (the model or planner said it was done) away from its target or short
  of its task.
- `cap`: a budget ran out: iterations, decisions, control ticks, the exploration budget.
- `veto`: the guarded motion layer refused or stopped the motion the episode ended on (a vetoed leg, a
  path still blocked after its replans, a safety stop), or the last motion was vetoed.
- `model_failure`: the model gave no usable answer (no valid action, choice or waypoints after the
  corrections) or another model error ended the run (outcome `aborted`).
- otherwise `wrong_place`: a failed run whose reason names none of the above ended where no target is.

The reasons are the planners' own one-line `end` reasons; the patterns below are the words they use.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any, Final

FAILURE_CAUSES: Final = (
    "collision",
    "not_found",
    "wrong_place",
    "cap",
    "veto",
    "model_failure",
    "outage",
)

_NOT_FOUND = re.compile(
    r"no sign found|no reachable frontier|no collision-free path|unreachable|not found|no landmark fits", re.I
)
_CAP = re.compile(r"max iterations|no finish within|budget|exhausted|decision cap|iteration cap", re.I)
_VETO = re.compile(r"veto|blocked \((obstacle|emergency)\)|motion stopped: (obstacle|emergency)", re.I)
_MODEL = re.compile(r"no valid (action|choice|answer|waypoints)", re.I)


def _outage(summary: Mapping[str, Any]) -> bool:
    metrics = summary.get("planner_metrics")
    reason = str(summary.get("reason") or "")
    return (
        (isinstance(metrics, dict) and metrics.get("failure") in ("backend", "sensor"))
        or bool(summary.get("cut_short"))
        or reason.startswith("crash:")
        or reason == "interrupted"
    )


def failure_cause(summary: Mapping[str, Any], last_action: Mapping[str, Any] | None = None) -> str | None:
    """The one cause of a run that did not succeed (one of FAILURE_CAUSES); None for a successful run.

    `summary` needs `success`, `outcome`, `reason`, `collisions`, `cut_short` and `planner_metrics` (as
    `llmnav.scoring.metrics.summarize_run` writes them); `last_action` is the run's last `action` event, if any.
    """
    if summary.get("success"):
        return None
    outcome = str(summary.get("outcome") or "aborted")
    reason = str(summary.get("reason") or "")
    metrics = summary.get("planner_metrics")
    if _outage(summary):
        return "outage"
    if (summary.get("collisions") or 0) > 0:
        return "collision"
    if outcome == "not_found" or (outcome == "failed" and _NOT_FOUND.search(reason)):
        return "not_found"
    if outcome == "completed":
        return "wrong_place"
    if _CAP.search(reason):
        return "cap"
    if _VETO.search(reason) or (last_action is not None and last_action.get("vetoed")):
        return "veto"
    if outcome == "aborted" or _MODEL.search(reason) or (isinstance(metrics, dict) and metrics.get("failure")):
        return "model_failure"
    return "wrong_place"
