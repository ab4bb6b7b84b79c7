"""The hybrid planner's own options, beyond the shared `DriveOptions` and `decide`."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from llmnav.planners.base import ChoiceOptions


class HybridOptions(ChoiceOptions):
    """What `-o KEY=VALUE` (or the named flags) may set for the hybrid planner."""

    menu_order: Literal["distance", "relevance"] = Field(
        default="distance", description="menu order: neutral by distance, or task-name matches first"
    )
    frames: Literal["sent", "always"] = Field(
        default="sent",
        description=(
            "camera frames rendered and stored: only those the model is sent, or every observation's "
            "(for the run viewer; 35-85 ms of CPU a decision)"
        ),
    )
    localize: bool = Field(
        default=True,
        description=(
            "sensed information: correct the odometry pose by matching each LiDAR scan to the map built so "
            "far (llmnav.nav.localize); false believes odometry alone"
        ),
    )
    explore: Literal["nearest", "utility", "scored"] = Field(
        default="utility",
        description=(
            "which frontier to explore: the nearest, the most useful (length x exp(-0.2/m x distance)), or "
            "scored by what has been seen near it (docs/frontier-values.md; a backend that cannot score "
            "explores by utility, and the run records it)"
        ),
    )
