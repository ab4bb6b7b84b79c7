"""The FSM's timing flags: `--model-latency MS|measured|recorded` and `--ttl MS|auto` into DriveOptions fields."""

from __future__ import annotations

import math
from typing import Any

from llmnav.errors import BadInputError


def timing_options(model_latency: str | None, ttl: str | None, backend: str | None = None) -> dict[str, Any]:
    """DriveOptions fields from `--model-latency MS|measured|recorded` and `--ttl MS|auto` (None: unset).

    Raises `BadInputError` (one line, exit 2) for a negative or unparseable latency, a TTL that is
    neither a positive number nor `auto`, or `recorded` with a backend that is not a replay.
    """
    fields: dict[str, Any] = {}
    if model_latency is not None:
        text = model_latency.strip().lower()
        if text in ("measured", "recorded"):
            if text == "recorded" and backend is not None and not backend.lower().startswith("replay:"):
                raise BadInputError("--model-latency recorded needs a replay backend (--backend replay:RUN_DIR)")
            fields["model_latency"] = text
        else:
            fields["model_latency"] = _number(text, "--model-latency", "MS (>= 0), measured or recorded")
            if fields["model_latency"] < 0:
                raise BadInputError(f"--model-latency {model_latency!r}: must be >= 0 ms")
    if ttl is not None:
        text = ttl.strip().lower()
        if text == "auto":
            fields["ttl_auto"] = True
        else:
            fields["ttl_ms"] = _number(text, "--ttl", "MS (> 0) or auto")
            if fields["ttl_ms"] <= 0:
                raise BadInputError(f"--ttl {ttl!r}: must be > 0 ms")
    return fields


def _number(text: str, flag: str, expected: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise BadInputError(f"{flag} {text!r}: expected {expected}") from None
    if not math.isfinite(value):
        raise BadInputError(f"{flag} {text!r}: expected {expected}")
    return value
