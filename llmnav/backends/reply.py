"""Reading a model server's reply as data: every field checked for type and range before it is used.

A server (or a recording of one) may send anything: `"usage": [1, 2]`, a token count of -5 or 1e30, a
log-probability of NaN, +40 or -1e308. Each reader here returns the value when it is what the field
means, `None` (or an empty container) when the field is absent or null, and raises a one-line
`ModelError` naming the field otherwise, so a broken reply ends a call the way a failed request does and
never reaches a decision, a table or a traceback.

Limits:
- a token count is an integer in 0..MAX_TOKEN_COUNT (no context window holds more);
- a token id is an integer in 0..MAX_TOKEN_ID;
- a log-probability [nats] is finite, at most 0 (+LOGPROB_ROUNDING for a server's float rounding) and at
  least MIN_TOKEN_LOGPROB per token: e^-1000 is far below anything a model's float logits give a token.
"""

from __future__ import annotations

import math
from typing import Any

from llmnav.core.chat import ContinuationScore
from llmnav.errors import ModelError

MAX_TOKEN_COUNT = 10_000_000  # [tokens] more than any context window; a larger count is a broken reply
MAX_TOKEN_ID = 2**31 - 1  # llama.cpp's token ids are int32
MIN_TOKEN_LOGPROB = -1000.0  # [nats per token] the floor of a believable log-probability
LOGPROB_ROUNDING = 1e-6  # [nats] a server may print -0.0 as 1e-7 after float32 rounding


def _kind(value: object) -> str:
    return "null" if value is None else type(value).__name__


def obj(value: object, where: str) -> dict[str, Any]:
    """A JSON object field (absent or null: empty)."""
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise ModelError(f"{where} is a {_kind(value)}, not an object")
    return value


def seq(value: object, where: str) -> list[Any]:
    """A JSON array field (absent or null: empty)."""
    if value is None:
        return []
    if not isinstance(value, list):
        raise ModelError(f"{where} is a {_kind(value)}, not an array")
    return value


def text_or_none(value: object, where: str) -> str | None:
    """A string field (absent or null: None)."""
    if value is None or isinstance(value, str):
        return value
    raise ModelError(f"{where} is a {_kind(value)}, not a string")


def _is_int(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def token_count(value: object, where: str) -> int | None:
    """A token count (absent or null: None); an integer in 0..MAX_TOKEN_COUNT."""
    if value is None:
        return None
    if not _is_int(value) or not 0 <= value <= MAX_TOKEN_COUNT:  # type: ignore[operator]
        raise ModelError(f"{where} is {_shown(value)}, not a token count (0..{MAX_TOKEN_COUNT})")
    return int(value)  # type: ignore[call-overload]


def token_ids(value: object, where: str) -> list[int]:
    """A non-empty list of token ids, each an integer in 0..MAX_TOKEN_ID."""
    if not isinstance(value, list) or not value or not all(_is_int(t) and 0 <= t <= MAX_TOKEN_ID for t in value):
        raise ModelError(f"{where} is not a list of token ids")
    return value


def usage_counts(usage: object, where: str, prompt: str, completion: str) -> tuple[int | None, int | None]:
    """(prompt tokens, completion tokens) from a usage object under the keys the provider uses."""
    block = obj(usage, where)
    counts = (token_count(block.get(key), f"{where}.{key}") for key in (prompt, completion))
    return next(counts), next(counts)


def duration(value: object, where: str) -> float | None:
    """A non-negative finite number (a duration, in whatever unit the field has; absent or null: None)."""
    if value is None:
        return None
    if not isinstance(value, (int, float)) or isinstance(value, bool) or not 0 <= value < math.inf:
        raise ModelError(f"{where} is {_shown(value)}, not a duration")
    return float(value)


def logprob(value: object, where: str) -> float:
    """One token's log-probability [nats]: finite, in MIN_TOKEN_LOGPROB..0."""
    number = float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else math.nan
    if not MIN_TOKEN_LOGPROB <= number <= LOGPROB_ROUNDING:  # NaN fails both comparisons
        raise ModelError(f"{where} is {_shown(value)}, not a log-probability ({MIN_TOKEN_LOGPROB:g}..0 nats a token)")
    return min(number, 0.0)


def continuation_score(total: object, tokens: object, where: str, *, probability: bool = True) -> ContinuationScore:
    """A continuation's summed score over `tokens` (≥ 1) tokens.

    With `probability` (a model's scores) the sum is a log-probability: finite, ≤ 0 and at least
    MIN_TOKEN_LOGPROB a token. Without it (a heuristic policy's scores, which may be positive) it must
    still be finite and within MIN_TOKEN_LOGPROB a token of zero either way.
    """
    count = token_count(tokens, f"{where} token count")
    if not count:
        raise ModelError(f"{where} token count is {_shown(tokens)}, not at least 1")
    number = float(total) if isinstance(total, (int, float)) and not isinstance(total, bool) else math.nan
    floor = MIN_TOKEN_LOGPROB * count
    top = LOGPROB_ROUNDING * count if probability else -floor
    if not floor <= number <= top:
        wanted = f"{floor:g}..0 nats for {count} token(s)" if probability else f"a finite score within ±{-floor:g}"
        raise ModelError(f"{where} is {_shown(total)}, not {wanted}")
    return ContinuationScore(min(number, 0.0) if probability else number, count)


def _shown(value: object) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:39] + "…"
