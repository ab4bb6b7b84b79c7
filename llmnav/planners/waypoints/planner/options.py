"""The waypoint planner's own options (source B's knobs), beyond the shared `DriveOptions`."""

from __future__ import annotations

from pydantic import Field

from llmnav.planners.base import ChoiceOptions


class WaypointOptions(ChoiceOptions):
    """What `-o KEY=VALUE` (or the named flags) may set for the waypoint planner; `decide` grounds the target."""

    max_generations: int = Field(default=5, ge=1, description="[replies] model plans tried until one validates")
    max_replans: int = Field(default=5, ge=0, description="[plans] replans after a stop on the way")
    replan_cooldown_s: float = Field(default=5.0, ge=0, description="[s] simulated time between two replans")
    preset_waypoints: tuple[tuple[float, float], ...] = Field(
        default=(), description="[m] a plan already made (`llmnav plan --execute`): driven, not asked for"
    )
