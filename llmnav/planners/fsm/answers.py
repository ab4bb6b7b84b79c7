"""The FSM assistant's answers: a velocity in m/s and rad/s, or [v, w] in milli-units inside the kinematic box."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Annotated, Any

from pydantic import Field, RootModel

from llmnav.guard.schemas import Answer, Number, response_schema


class VelocitySuggestion(Answer):
    """The FSM assistant's answer: a velocity command [m/s], [rad/s] (kinematic limits checked by the FSM)."""

    linear_x: Number
    angular_z: Number


# A two-number array rather than an object: every output token costs a decoding step, even the ones a
# grammar forces, and `[12,-150]` is 7 tokens against 13 for `{"v":12,"w":-150}`.
class VelocityMilli(RootModel[tuple[Annotated[int, Field(strict=True)], Annotated[int, Field(strict=True)]]]):
    """The FSM assistant's answer [v, w]: whole mm/s and mrad/s (positive w turns left)."""

    @property
    def v(self) -> int:
        """Linear velocity [mm/s]."""
        return self.root[0]

    @property
    def w(self) -> int:
        """Angular velocity [mrad/s]."""
        return self.root[1]


@dataclass(frozen=True)
class VelocityBox:
    """The admissible box of a `VelocityMilli` answer, in its whole milli-units: what its schema states.

    v_min <= v <= v_max [mm/s], |w| <= w_max [mrad/s]. Passed to the guard as its bounds, so an answer
    outside the box is rejected (and logged) as `bounds` by the guard itself.
    """

    v_min: int  # [mm/s]
    v_max: int  # [mm/s]
    w_max: int  # [mrad/s]

    @classmethod
    def of(cls, v_min: float, v_max: float, w_max: float) -> VelocityBox:
        """The whole milli-units inside a box given in m/s and rad/s (rounded inward)."""
        return cls(math.ceil(v_min * 1000), math.floor(v_max * 1000), math.floor(w_max * 1000))

    def check(self, value: Any) -> str | None:
        """Why a `VelocityMilli` lies outside the box, or None when it is admissible."""
        answer: VelocityMilli = value
        if not (self.v_min <= answer.v <= self.v_max and -self.w_max <= answer.w <= self.w_max):
            return (
                f"[{answer.v}, {answer.w}] is outside {self.v_min} <= v <= {self.v_max} mm/s, "
                f"|w| <= {self.w_max} mrad/s"
            )
        return None


def velocity_schema(v_min: float, v_max: float, w_max: float) -> dict[str, Any]:
    """`VelocityMilli`'s JSON Schema with the kinematic box (`VelocityBox.of`) as integer minimum/maximum.

    Under llama.cpp's grammar an out-of-box value cannot be decoded; other backends get the same schema
    and their answers are judged against the same box by the guard (`VelocityBox` as its bounds).
    """
    box = VelocityBox.of(v_min, v_max, w_max)
    schema = response_schema(VelocityMilli)
    v_item, w_item = schema["prefixItems"]
    v_item.update(minimum=box.v_min, maximum=box.v_max)
    w_item.update(minimum=-box.w_max, maximum=box.w_max)
    schema["items"] = False  # nothing after the two numbers
    return schema
