"""The waypoint planner's answers: a waypoint list and its size bound, and the grounding choice of a target object."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Annotated, Any, Literal

from pydantic import Field, RootModel, create_model

from llmnav.guard.schemas import MAX_ID_CHARS, Answer, Number, cap


class Waypoint(Answer):
    """A waypoint in the map frame [m]."""

    x: Number
    y: Number


class WaypointList(RootModel[list[Waypoint]]):
    """The waypoint planner's answer: a bare JSON array of at least one {x, y}."""

    root: Annotated[list[Waypoint], Field(min_length=1)]

    @property
    def points(self) -> list[tuple[float, float]]:
        """The waypoints as (x, y) tuples [m]."""
        return [(w.x, w.y) for w in self.root]


@dataclass(frozen=True)
class WaypointBounds:
    """How many waypoints a plan may have (corridor and spacing rules are the waypoint planner's)."""

    max_waypoints: int = 6

    def check(self, value: Any) -> str | None:
        """Too many waypoints, or None."""
        points = value.root if isinstance(value, WaypointList) else value
        if len(points) > self.max_waypoints:
            return f"the plan has {len(points)} waypoints; at most {self.max_waypoints} are allowed"
        return None


class TargetChoice(Answer):
    """The grounding answer: which listed object a command refers to."""

    object_id: Annotated[str, Field(strict=True), cap(MAX_ID_CHARS)]


@lru_cache(maxsize=256)
def target_choice_model(object_ids: tuple[str, ...]) -> type[TargetChoice]:
    """A `TargetChoice` whose `object_id` must be one of `object_ids` (a string enum)."""
    if not object_ids:
        raise ValueError("a target choice needs at least one object id")
    allowed = Literal[tuple(dict.fromkeys(object_ids))]  # type: ignore[valid-type]
    return create_model(
        "TargetChoice",
        __base__=TargetChoice,
        object_id=(allowed, ...),  # type: ignore[arg-type]
    )
