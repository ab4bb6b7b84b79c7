"""The shapes a model's answer may take (pydantic v2), and the JSON Schemas backends send for them.

Every model here is deliberately plain — objects, strings, numbers, string/int enums, one array — so
that its schema works both for llama.cpp's JSON-Schema-to-grammar constrained decoding and for Gemini's
OpenAPI subset. `response_schema(model)` returns that schema with every `$ref` inlined and titles dropped.

Validation here is *shape* only: types, required keys, no unknown keys, finite numbers, capped strings.
Range rules (how far a FRONT may go, how many waypoints) are bounds, checked separately by
`llmnav.guard.parse` so a rejection is classified correctly (schema vs bounds).
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from enum import StrEnum
from functools import lru_cache
from typing import Annotated, Any, Literal, Protocol

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, RootModel, create_model, field_validator

MAX_TEXT_CHARS = 2000  # cap on each free-text field; longer means a runaway answer, not a thought
MAX_ID_CHARS = 200  # cap on identifiers


def _cap(limit: int) -> Any:
    """A validator capping string length (kept out of the JSON Schema: long `maxLength`s bloat grammars)."""

    def check(text: str) -> str:
        if len(text) > limit:
            raise ValueError(f"text is {len(text)} characters long; the limit is {limit}")
        return text

    return AfterValidator(check)


# Strict: a string must be a string (no numbers coerced), a number a number (ints fine, bools and
# numeric strings not), and NaN/Infinity are rejected by `allow_inf_nan=False` on every model below.
Text = Annotated[str, Field(strict=True), _cap(MAX_TEXT_CHARS)]
Number = Annotated[float, Field(strict=True)]


class _Answer(BaseModel):
    """Base of every answer model: unknown keys rejected, numbers finite."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, frozen=True)


class ActionCommand(StrEnum):
    """The stepwise planner's discrete commands (units: FRONT/BACK metres, ROTATE_* degrees)."""

    FRONT = "FRONT"
    BACK = "BACK"
    ROTATE_LEFT = "ROTATE_LEFT"  # counter-clockwise
    ROTATE_RIGHT = "ROTATE_RIGHT"  # clockwise
    COMPLETE = "COMPLETE"


class ActionSpec(_Answer):
    """One command and its single numeric parameter ([m] for FRONT/BACK, [deg] for rotations, 0 to finish)."""

    command: ActionCommand
    parameters: Number

    @field_validator("command", mode="before")
    @classmethod
    def _normalise_case(cls, value: object) -> object:
        # Forgive case and surrounding blanks ("front "), but only for pure-ASCII text: a look-alike such
        # as "FRОNT" with a Cyrillic О must stay unknown rather than be "fixed" into a motion.
        if isinstance(value, str) and value.isascii():
            return value.strip().upper()
        return value


class StepAction(_Answer):
    """The stepwise planner's answer: what it is after, why, what it sees, and one action."""

    goal: Text
    reasoning: Text
    scene_description: Text
    action: ActionSpec


def step_answer(command: Any, parameters: Any, **fields: Any) -> dict[str, Any]:
    """A stepwise answer as a JSON-able dict: the action plus placeholder texts, any field replaced or added.

    Values are not checked (hostile ones are the point in fuzzing): scripted runs, tests and examples build
    answers with it, and the guard judges them like any model's.
    """
    body: dict[str, Any] = {
        "goal": "reach the target",
        "reasoning": "it looks right",
        "scene_description": "a room",
        "action": {"command": command, "parameters": parameters},
    }
    body.update(fields)
    return body


class Waypoint(_Answer):
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


class VelocitySuggestion(_Answer):
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


class HybridChoice(_Answer):
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


class TargetChoice(_Answer):
    """The grounding answer: which listed object a command refers to."""

    object_id: Annotated[str, Field(strict=True), _cap(MAX_ID_CHARS)]


# --- answer models restricted to the valid choices --------------------------------------------------


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


# --- the schema a backend sends ---------------------------------------------------------------------


def _inline(node: Any, defs: dict[str, Any]) -> Any:
    """Copy of a schema node with `$ref`s replaced by their definitions and titles dropped."""
    if isinstance(node, dict):
        if "$ref" in node:
            name = node["$ref"].rsplit("/", 1)[-1]
            return _inline(defs[name], defs)
        out: dict[str, Any] = {}
        for key, value in node.items():
            if key in ("title", "$defs"):
                continue
            if key == "properties":  # property *names* may be "title"; keep them all
                out[key] = {k: _inline(v, defs) for k, v in value.items()}
            else:
                out[key] = _inline(value, defs)
        # A single-valued enum arrives as `const`; Gemini only knows `enum`.
        if "const" in out and "enum" not in out:
            out["enum"] = [out.pop("const")]
        return out
    if isinstance(node, list):
        return [_inline(item, defs) for item in node]
    return node


@lru_cache(maxsize=256)
def _response_schema_cached(model: type[BaseModel]) -> dict[str, Any]:
    raw = model.model_json_schema()
    schema = _inline(raw, raw.get("$defs", {}))
    assert isinstance(schema, dict)
    return schema


def response_schema(model: type[BaseModel]) -> dict[str, Any]:
    """The JSON Schema to send with a request for `model`: self-contained (no `$ref`), no titles.

    A fresh copy each call, so a backend may adapt it (e.g. to Gemini's casing) without harm.
    """
    return copy.deepcopy(_response_schema_cached(model))


# --- bounds: range rules checked after the shape is valid ------------------------------------------


class Bounds(Protocol):
    """A range rule on an already schema-valid answer; `check` says what is wrong, or None."""

    def check(self, value: Any) -> str | None:
        """The problem with `value` in one sentence, or None when it is within bounds."""
        ...


def _shown(value: float) -> str:
    """`value` short (`1e+09`, `360`) unless that rounds it: `360.0000000001` must not read as `360`."""
    short = f"{value:g}"
    return short if float(short) == value else repr(value)


@dataclass(frozen=True)
class ActionBounds:
    """Ranges of a stepwise action's parameter.

    FRONT/BACK: 0 < metres ≤ `max_step_m`; ROTATE_*: 0 < degrees ≤ `max_rotate_deg`; COMPLETE: exactly 0.
    Decision: COMPLETE with any other number is a bounds error (the prompt says "COMPLETE, 0"), so a model
    that muddles parameters is told so instead of silently passing; the correction turn is cheap.
    """

    max_step_m: float = 5.0  # [m]
    max_rotate_deg: float = 360.0  # [deg]

    def check(self, value: Any) -> str | None:
        """See the class docstring; `value` is a `StepAction` (or its `ActionSpec`)."""
        spec: ActionSpec = value.action if isinstance(value, StepAction) else value
        cmd, p = spec.command, spec.parameters
        if cmd in (ActionCommand.FRONT, ActionCommand.BACK):
            if not 0.0 < p <= self.max_step_m:
                return f"{cmd} takes metres with 0 < parameters <= {self.max_step_m:g}; got {_shown(p)}"
        elif cmd in (ActionCommand.ROTATE_LEFT, ActionCommand.ROTATE_RIGHT):
            if not 0.0 < p <= self.max_rotate_deg:
                return f"{cmd} takes degrees with 0 < parameters <= {self.max_rotate_deg:g}; got {_shown(p)}"
        elif p != 0.0:
            return f"COMPLETE takes parameters 0; got {p:g}"
        return None


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


# --- the robot's kinematic box (the guarded motion layer clips every velocity command onto it) -----


@dataclass(frozen=True)
class VelocityLimits:
    """Admissible box for a velocity command: |v| ≤ v_max [m/s], |ω| ≤ w_max [rad/s]."""

    v_max: float  # [m/s]
    w_max: float  # [rad/s]

    def check(self, value: Any) -> str | None:
        """Why a `VelocitySuggestion` lies outside the box, or None when it is admissible."""
        suggestion: VelocitySuggestion = value
        return self.violation(suggestion.linear_x, suggestion.angular_z)

    def violation(self, linear_x: float, angular_z: float) -> str | None:
        """Why the command (linear_x [m/s], angular_z [rad/s]) lies outside the box, or None."""
        if not (math.isfinite(linear_x) and abs(linear_x) <= self.v_max):
            return f"linear_x {linear_x:g} m/s is outside [-{self.v_max:g}, {self.v_max:g}]"
        if not (math.isfinite(angular_z) and abs(angular_z) <= self.w_max):
            return f"angular_z {angular_z:g} rad/s is outside [-{self.w_max:g}, {self.w_max:g}]"
        return None

    def project(self, linear_x: float, angular_z: float) -> tuple[float, float]:
        """Clip a command onto the box (source C's projection Π)."""
        return (
            min(max(linear_x, -self.v_max), self.v_max),
            min(max(angular_z, -self.w_max), self.w_max),
        )
