"""Pure helpers of the shared HTTP layer: retry-delay parsing, backoff bounds, redaction, options."""

from __future__ import annotations

import random
from datetime import UTC, datetime

import pytest

from llmnav.backends.http import (
    HttpOptions,
    backoff_delay,
    normalise_url,
    one_line,
    parse_options,
    parse_retry_delay,
    redact,
)
from llmnav.errors import BackendSpecError


def test_parse_retry_delay_forms():
    now = datetime(2026, 1, 1, 12, 0, 0, tzinfo=UTC)
    assert parse_retry_delay("7") == 7.0
    assert parse_retry_delay("7s") == 7.0
    assert parse_retry_delay("0.25s") == 0.25
    assert parse_retry_delay("Thu, 01 Jan 2026 12:00:30 GMT", now) == 30.0
    assert parse_retry_delay("Thu, 01 Jan 2026 11:00:00 GMT", now) == 0.0  # in the past: go now
    assert parse_retry_delay("soon") is None


def test_backoff_grows_with_jitter_and_cap():
    rng = random.Random(1)
    for retry, ceiling in [(1, 1.0), (2, 2.0), (3, 4.0), (6, 10.0), (20, 10.0)]:
        draws = [backoff_delay(retry, 1.0, 10.0, rng) for _ in range(200)]
        assert all(ceiling / 2 <= d <= ceiling for d in draws)
        assert max(draws) - min(draws) > ceiling / 10  # jittered, not constant


def test_redact_known_secrets_and_query_keys():
    text = "GET https://x/v1?key=AIzaSECRET&alt=json failed; header sk-abc123 rejected"
    out = redact(text, ["sk-abc123", ""])
    assert "AIzaSECRET" not in out and "sk-abc123" not in out
    assert "key=***&alt=json" in out and "header *** rejected" in out


def test_one_line_collapses_and_shortens():
    assert one_line("a\n b\t\tc") == "a b c"
    long = one_line("x" * 500, 50)
    assert len(long) == 50 and long.endswith("…")


def test_normalise_url():
    assert normalise_url("localhost:11434/") == "http://localhost:11434"
    assert normalise_url("http://0.0.0.0:8080") == "http://127.0.0.1:8080"


def test_parse_options_is_strict_and_one_line():
    assert parse_options(HttpOptions, "x", {"max_retries": 0}).max_retries == 0
    with pytest.raises(BackendSpecError) as info:
        parse_options(HttpOptions, "ollama", {"max_retries": -1})
    assert "\n" not in str(info.value) and "max_retries" in str(info.value)
