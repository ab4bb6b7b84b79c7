"""What every answer model shares (pydantic v2), and the JSON Schemas backends send for them.

Each planner owns its answer models (`llmnav.planners.<name>.answers`); they build on `Answer`, `Text` and
`Number` here.

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
from functools import lru_cache
from typing import Annotated, Any, Protocol

from pydantic import AfterValidator, BaseModel, ConfigDict, Field

MAX_TEXT_CHARS = 2000  # cap on each free-text field; longer means a runaway answer, not a thought
MAX_ID_CHARS = 200  # cap on identifiers


def cap(limit: int) -> Any:
    """A validator capping string length (kept out of the JSON Schema: long `maxLength`s bloat grammars)."""

    def check(text: str) -> str:
        if len(text) > limit:
            raise ValueError(f"text is {len(text)} characters long; the limit is {limit}")
        return text

    return AfterValidator(check)


# Strict: a string must be a string (no numbers coerced), a number a number (ints fine, bools and
# numeric strings not), and NaN/Infinity are rejected by `allow_inf_nan=False` on every model below.
Text = Annotated[str, Field(strict=True), cap(MAX_TEXT_CHARS)]
Number = Annotated[float, Field(strict=True)]


class Answer(BaseModel):
    """Base of every answer model: unknown keys rejected, numbers finite."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, frozen=True)


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


def shown(value: float) -> str:
    """`value` short (`1e+09`, `360`) unless that rounds it: `360.0000000001` must not read as `360`."""
    short = f"{value:g}"
    return short if float(short) == value else repr(value)


# --- the robot's kinematic box (the guarded motion layer clips every velocity command onto it) -----


@dataclass(frozen=True)
class VelocityLimits:
    """Admissible box for a velocity command: |v| ≤ v_max [m/s], |ω| ≤ w_max [rad/s]."""

    v_max: float  # [m/s]
    w_max: float  # [rad/s]

    def check(self, value: Any) -> str | None:
        """Why a velocity answer (`linear_x`, `angular_z`) lies outside the box, or None when it is admissible."""
        return self.violation(value.linear_x, value.angular_z)

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
