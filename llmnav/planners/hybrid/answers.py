"""The hybrid planner's answer: one numbered option of its menu, and a reason."""

from __future__ import annotations

from functools import lru_cache
from typing import Annotated, Literal

from pydantic import Field, create_model, field_validator

from llmnav.guard.schemas import Answer, Text


class HybridChoice(Answer):
    """The hybrid planner's answer: one numbered option and a short reason."""

    reasoning: Text
    option: Annotated[int, Field(strict=True)]

    @field_validator("option", mode="before")
    @classmethod
    def _no_bool(cls, value: object) -> object:
        # JSON true is not option 1 (restricted subclasses use a Literal, which would accept it).
        if isinstance(value, bool):
            raise ValueError("option must be an integer, not true/false")
        return value


@lru_cache(maxsize=256)
def hybrid_choice_model(options: tuple[int, ...]) -> type[HybridChoice]:
    """A `HybridChoice` whose `option` must be one of `options` (a JSON-Schema enum, so grammars enforce it).

    Cached per tuple of options, so asking again for the same menu costs nothing.
    """
    if not options:
        raise ValueError("a hybrid choice needs at least one option")
    allowed = Literal[tuple(sorted(set(options)))]  # type: ignore[valid-type]
    return create_model(
        "HybridChoice",
        __base__=HybridChoice,
        option=(allowed, ...),  # type: ignore[arg-type]
    )
