"""Turn a model's raw text into a validated value, or a classified rejection — never an exception.

Pipeline: extract → (repair) → schema → bounds.

1. Extract candidates, best first: bodies of ```json fences, then of bare ``` fences, then the whole
   text; inside each, every balanced {...} (or [...] when the answer is a list) found by string-aware
   bracket matching (a `}` inside a JSON string does not close anything). An opener that never closes
   (a truncated answer) yields its tail as a candidate for repair.
2. A candidate is parsed with `json.loads`; if that fails, `json_repair` fixes small slips (trailing commas,
   single quotes, unquoted keys, missing closing brackets) and the result notes `repaired=True`.
3. The parsed value is validated with the pydantic model (shape: types, keys, finite numbers, capped strings).
4. The optional bounds rule checks ranges.

The first candidate that passes wins (so with several JSON objects the first valid one is taken). A
rejection reports the first failure met, classified:
- `parse`: no JSON value could be read at all;
- `schema`: JSON was read but has the wrong shape (missing/extra keys, wrong types, NaN/Infinity,
  unknown command such as a look-alike "FRОNT");
- `bounds`: the shape is right but a value is out of range (FRONT 1e308, ROTATE_LEFT 0, too many waypoints).
"""

from __future__ import annotations

import json
import re
import reprlib
from dataclasses import dataclass
from functools import lru_cache
from typing import Any, Generic, Literal, TypeVar

from pydantic import BaseModel, RootModel, TypeAdapter, ValidationError

from llmnav.guard.schemas import Bounds, response_schema

T = TypeVar("T")
Outcome = Literal["ok", "parse", "schema", "bounds"]

MAX_ANSWER_CHARS = 100_000  # longer answers are rejected unread: no valid answer is that long
MAX_REPAIR_CHARS = 20_000  # json_repair is pure Python; do not feed it novels
MAX_CANDIDATES = 12  # balanced segments examined per answer
MAX_REPAIRS = 3  # repair attempts per answer

_JSON_FENCE = re.compile(r"```[ \t]*json[^\n]*\n?", re.IGNORECASE)
_TOKENS = re.compile(r'[\[\]{}"\\]')
_CLOSER = {"{": "}", "[": "]"}

_short = reprlib.Repr()
_short.maxstring = 40
_short.maxother = 40
_short.maxdict = 3
_short.maxlist = 3
_short.maxlevel = 2


@dataclass
class GuardResult(Generic[T]):
    """What the guard made of one answer."""

    value: T | None  # the validated value (None unless outcome == "ok")
    outcome: Outcome
    error: str | None  # one or a few sentences naming the exact problem (None when ok)
    repaired: bool = False  # the JSON needed json_repair to parse
    extracted: str | None = None  # the JSON text that was validated or rejected (capped at 2000 chars)

    @property
    def ok(self) -> bool:
        """Whether the answer is usable."""
        return self.outcome == "ok"


# --- extraction -------------------------------------------------------------------------------------


def _bracket_pairs(text: str) -> list[tuple[int, int | None]]:
    """(opener position, matching closer position or None) for every bracket, in one linear pass.

    Quotes count only inside brackets (prose like `the "box"` cannot confuse it), backslash escapes are
    honoured inside strings, and a wrongly nested closer leaves every open bracket unclosed.
    """
    pairs: list[tuple[int, int | None]] = []
    stack: list[tuple[str, int]] = []  # (expected closer, index into pairs)
    in_string = False
    escaped_at = -1
    for m in _TOKENS.finditer(text):
        ch, pos = m.group(), m.start()
        if in_string:
            if pos == escaped_at:
                continue
            if ch == "\\":
                escaped_at = pos + 1
            elif ch == '"':
                in_string = False
            continue
        if ch == '"':
            in_string = bool(stack)
        elif ch in _CLOSER:
            stack.append((_CLOSER[ch], len(pairs)))
            pairs.append((pos, None))
        elif ch in "}]" and stack:
            closer, index = stack.pop()
            if closer == ch:
                pairs[index] = (pairs[index][0], pos)
            else:
                stack.clear()  # broken nesting: leave the rest unclosed, for repair
    return pairs


def _segments(text: str, openers: str, budget: int) -> list[tuple[str, bool]]:
    """Balanced (segment, True) and never-closing (tail, False) candidates in order of position.

    Only brackets in `openers` start candidates; those inside an earlier balanced candidate are skipped
    (they are parts of it), those inside an unclosed one are kept (the outer one may be beyond repair).
    """
    found: list[tuple[str, bool]] = []
    covered_to = -1
    for start, end in _bracket_pairs(text):
        if len(found) >= budget:
            break
        if start <= covered_to or text[start] not in openers:
            continue
        if end is None:
            found.append((text[start:], False))
        else:
            found.append((text[start : end + 1], True))
            covered_to = end
    return found


def _fence_bodies(text: str) -> list[str]:
    """Bodies of ```json fences first, then of any fence (a missing closing fence runs to the end)."""
    bodies: list[str] = []
    for m in _JSON_FENCE.finditer(text):
        close = text.find("```", m.end())
        bodies.append(text[m.end() :] if close < 0 else text[m.end() : close])
    parts = text.split("```")
    for body in parts[1::2]:
        first_line, _, rest = body.partition("\n")
        bodies.append(rest if first_line.strip().isalnum() or not first_line.strip() else body)
    return bodies


def _candidates(text: str, openers: str) -> list[tuple[str, bool]]:
    """Distinct candidates, fenced ones first, at most MAX_CANDIDATES."""
    seen: set[str] = set()
    out: list[tuple[str, bool]] = []
    for source in (*_fence_bodies(text), text):
        for seg, balanced in _segments(source, openers, MAX_CANDIDATES):
            if seg not in seen:
                seen.add(seg)
                out.append((seg, balanced))
            if len(out) >= MAX_CANDIDATES:
                return out
    return out


def _load(segment: str, balanced: bool, repairs_left: int) -> tuple[Any, bool] | None:
    """(value, repaired) for a candidate, or None when it holds no JSON."""
    if balanced:
        try:
            return json.loads(segment), False
        except (ValueError, RecursionError):
            pass
    if repairs_left <= 0 or len(segment) > MAX_REPAIR_CHARS:
        return None
    try:
        # deferred: json_repair (about 0.03 s) loads only for broken answers
        import json_repair

        value = json_repair.repair_json(segment, return_objects=True)
    except Exception:  # noqa: BLE001 - a third-party repairer on hostile text may fail in any way
        return None
    if value in ("", None):
        return None
    return value, True


# --- validation -------------------------------------------------------------------------------------


@lru_cache(maxsize=64)
def _adapter(model: Any) -> TypeAdapter[Any]:
    return TypeAdapter(model)


def _validate(model: Any, value: Any) -> Any:
    if isinstance(model, type) and issubclass(model, BaseModel):
        return model.model_validate(value)
    return _adapter(model).validate_python(value)


def _expects_list(model: Any) -> bool | None:
    """True for list answers, False for object answers, None when unknown."""
    if isinstance(model, type) and issubclass(model, RootModel):
        annotation = model.model_fields["root"].annotation
        origin = getattr(annotation, "__origin__", annotation)
        return origin in (list, tuple)
    if isinstance(model, type) and issubclass(model, BaseModel):
        return False
    origin = getattr(model, "__origin__", None)
    return True if origin in (list, tuple) else None


def _where(loc: tuple[int | str, ...]) -> str:
    out = ""
    for part in loc:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out or "(top level)"


def describe_validation_error(err: ValidationError, limit: int = 3) -> str:
    """A short, exact account of what is wrong with the JSON (first `limit` problems)."""
    parts: list[str] = []
    for item in err.errors(include_url=False)[:limit]:
        where = _where(tuple(item["loc"]))
        kind = item["type"]
        if kind == "missing":
            parts.append(f"{where}: required field is missing")
        elif kind == "extra_forbidden":
            parts.append(f"{where}: field is not allowed")
        else:
            msg = str(item["msg"]).removeprefix("Value error, ")
            parts.append(f"{where}: {msg} (got {_short.repr(item.get('input'))})")
    more = err.error_count() - limit
    return "; ".join(parts) + (f"; and {more} more problem(s)" if more > 0 else "")


# --- the entry point --------------------------------------------------------------------------------


def parse_answer(text: object, model: type[T] | Any, *, bounds: Bounds | None = None) -> GuardResult[T]:
    """Extract, repair, validate and bounds-check a model answer. Never raises on any `text`.

    `model` is a pydantic model class (e.g. `StepAction`, `WaypointList`) or any type pydantic can
    validate (e.g. `list[Waypoint]`). `bounds` is an optional range rule (`ActionBounds`, ...).
    """
    try:
        return _parse(text, model, bounds)
    except Exception as err:  # noqa: BLE001 - the contract is "never raises"; classify what slipped through
        return GuardResult(None, "parse", f"the answer could not be read ({type(err).__name__})")


def _parse(text: object, model: Any, bounds: Bounds | None) -> GuardResult[Any]:
    if isinstance(text, bytes):
        text = text.decode("utf-8", errors="replace")
    if not isinstance(text, str):
        return GuardResult(None, "parse", f"the answer is not text ({type(text).__name__})")
    if len(text) > MAX_ANSWER_CHARS:
        return GuardResult(
            None, "parse", f"the answer is {len(text)} characters long; at most {MAX_ANSWER_CHARS} are read"
        )
    wants_list = _expects_list(model)
    openers = "[" if wants_list else "{" if wants_list is False else "{["
    first_failure: GuardResult[Any] | None = None
    repairs_left = MAX_REPAIRS
    for segment, balanced in _candidates(text, openers):
        loaded = _load(segment, balanced, repairs_left)
        if loaded is None:
            continue
        value, repaired = loaded
        repairs_left -= int(repaired)
        if wants_list is not None and isinstance(value, list) != wants_list:
            continue  # e.g. repair turned prose "[a box]" into a list while an object is expected
        snippet = segment[:2000]
        try:
            parsed = _validate(model, value)
        except ValidationError as err:
            first_failure = first_failure or GuardResult(
                None, "schema", describe_validation_error(err), repaired, snippet
            )
            continue
        problem = bounds.check(parsed) if bounds is not None else None
        if problem is not None:
            first_failure = first_failure or GuardResult(None, "bounds", problem, repaired, snippet)
            continue
        return GuardResult(parsed, "ok", None, repaired, snippet)
    if first_failure is not None:
        return first_failure
    kind = "JSON array" if wants_list else "JSON object" if wants_list is False else "JSON value"
    return GuardResult(None, "parse", f"no {kind} could be found or repaired in the answer")


def correction_message(result: GuardResult[Any], schema: dict[str, Any] | type[BaseModel]) -> str:
    """The follow-up that tells the model exactly what was wrong and what shape is expected."""
    if result.ok:
        raise ValueError("correction_message needs a rejected result")
    if isinstance(schema, type):
        schema = response_schema(schema)
    what = {
        "parse": "I could not find valid JSON in it",
        "schema": "its JSON does not have the required structure",
        "bounds": "a value in it is outside the allowed range",
    }[result.outcome]
    shape = "array" if schema.get("type") == "array" else "object"
    return (
        f"Your previous answer cannot be used: {what}.\n"
        f"Problem: {result.error}\n"
        f"Answer again with a single corrected JSON {shape} that follows this JSON Schema exactly, "
        f"inside a ```json fence, with nothing else:\n"
        f"```json\n{json.dumps(schema, indent=1)}\n```"
    )
