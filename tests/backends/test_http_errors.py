"""Failure handling shared by the three HTTP backends, against a real loopback server.

Each test runs for ollama, gemini and openai: 429 with a server-given delay, 500 then success, 500 forever,
read timeout, garbage body, connection refused, non-retryable 4xx, and that no API key leaks.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from datetime import UTC, datetime, timedelta
from email.utils import format_datetime
from typing import Any

import pytest

from llmnav.backends.base import Backend, ChatRequest, Message
from llmnav.backends.gemini import GeminiBackend
from llmnav.backends.ollama import OllamaBackend
from llmnav.backends.openai import OpenAIBackend
from llmnav.errors import ModelError

FAKE_KEY = "sk-test-SECRET-0123456789abcdef"
REQUEST = ChatRequest((Message("user", "go"),), json_schema={"type": "object"})


def ok_body(kind: str, text: str) -> dict[str, Any]:
    """A minimal successful reply in each provider's format."""
    if kind == "ollama":
        return {
            "model": "m",
            "message": {"role": "assistant", "content": text},
            "done": True,
            "prompt_eval_count": 3,
            "eval_count": 4,
        }
    if kind == "gemini":
        return {
            "candidates": [{"content": {"role": "model", "parts": [{"text": text}]}, "finishReason": "STOP"}],
            "usageMetadata": {"promptTokenCount": 3, "candidatesTokenCount": 4},
        }
    return {
        "model": "m",
        "choices": [{"message": {"role": "assistant", "content": text}, "finish_reason": "stop"}],
        "usage": {"prompt_tokens": 3, "completion_tokens": 4},
    }


def error_body(kind: str, code: int, message: str) -> dict[str, Any]:
    if kind == "ollama":
        return {"error": message}
    return {"error": {"code": code, "message": message, "status": "UNAVAILABLE"}}


MakeBackend = Callable[..., Backend]


@pytest.fixture(params=["ollama", "gemini", "openai"])
def kind(request: pytest.FixtureRequest) -> str:
    return str(request.param)


@pytest.fixture
def make(kind: str, monkeypatch: pytest.MonkeyPatch, fast: dict[str, Any]) -> MakeBackend:
    """Build the backend of `kind` pointing at a URL, with a fake key in the environment."""
    monkeypatch.setenv("GEMINI_API_KEY", FAKE_KEY)
    monkeypatch.setenv("OPENAI_API_KEY", FAKE_KEY)

    def build(url: str, **options: Any) -> Backend:
        opts = {**fast, **options}
        if kind == "ollama":
            return OllamaBackend("m", base_url=url, **opts)
        if kind == "gemini":
            return GeminiBackend("m", base_url=url, **opts)
        return OpenAIBackend(f"m@{url}/v1", **opts)

    return build


def assert_one_line_without_key(err: BaseException) -> None:
    text = str(err)
    assert "\n" not in text
    assert FAKE_KEY not in text and FAKE_KEY not in repr(err)
    assert err.__context__ is None or FAKE_KEY not in repr(err.__context__)


def test_success_returns_text_tokens_latency(kind, make, server):
    server.push(server.reply(200, ok_body(kind, '{"a": 1}')))
    backend = make(server.url)
    result = backend.chat(REQUEST)
    assert result.text == '{"a": 1}'
    assert (result.prompt_tokens, result.completion_tokens) == (3, 4)
    assert 0 < result.latency_s < 2
    assert result.meta["attempts"] == 1
    assert len(server.seen) == 1 and server.seen[0].method == "POST"
    assert FAKE_KEY not in repr(backend) and FAKE_KEY not in backend.spec
    backend.close()


def test_429_honours_retry_after_header(kind, make, server, sleeps):
    server.push(
        server.reply(429, error_body(kind, 429, "slow down"), {"Retry-After": "7"}),
        server.reply(200, ok_body(kind, "fine")),
    )
    result = make(server.url, sleep=sleeps.append).chat(REQUEST)
    assert result.text == "fine"
    assert sleeps == [7.0]  # exactly the server's delay, not our backoff
    assert result.meta["attempts"] == 2


def test_429_honours_http_date_retry_after(kind, make, server, sleeps):
    when = format_datetime(datetime.now(UTC) + timedelta(seconds=30), usegmt=True)
    server.push(
        server.reply(429, error_body(kind, 429, "slow down"), {"Retry-After": when}),
        server.reply(200, ok_body(kind, "fine")),
    )
    assert make(server.url, sleep=sleeps.append).chat(REQUEST).text == "fine"
    assert len(sleeps) == 1 and 27.0 <= sleeps[0] <= 30.0


def test_429_gemini_retry_info_delay(kind, make, server, sleeps):
    body = {
        "error": {
            "code": 429,
            "message": "Resource has been exhausted",
            "status": "RESOURCE_EXHAUSTED",
            "details": [
                {"@type": "type.googleapis.com/google.rpc.QuotaFailure"},
                {"@type": "type.googleapis.com/google.rpc.RetryInfo", "retryDelay": "12s"},
            ],
        }
    }
    server.push(server.reply(429, body), server.reply(200, ok_body(kind, "fine")))
    assert make(server.url, sleep=sleeps.append).chat(REQUEST).text == "fine"
    assert sleeps == [12.0]


def test_server_delay_over_the_cap_gives_up_at_once(kind, make, server, sleeps):
    server.default = server.reply(429, error_body(kind, 429, "quota"), {"Retry-After": "3600"})
    with pytest.raises(ModelError) as info:
        make(server.url, sleep=sleeps.append, retry_after_max_s=60).chat(REQUEST)
    assert sleeps == [] and len(server.seen) == 1
    assert "429" in str(info.value) and "3600 s" in str(info.value)
    assert_one_line_without_key(info.value)


def test_500_then_success_with_real_backoff(kind, make, server):
    server.push(
        server.reply(500, error_body(kind, 500, "boom")),
        server.reply(503, error_body(kind, 503, "busy")),
        server.reply(200, ok_body(kind, "third time")),
    )
    t0 = time.perf_counter()
    result = make(server.url, backoff_base_s=0.05).chat(REQUEST)
    waited = time.perf_counter() - t0
    assert result.text == "third time" and result.meta["attempts"] == 3
    # backoff draws in [0.5, 1] x (0.05, 0.10) s: at least 0.075 s of real waiting, and it was counted
    assert waited >= 0.075 and result.latency_s >= 0.075


def test_500_forever_is_bounded_and_one_line(kind, make, server, sleeps):
    server.default = server.reply(500, error_body(kind, 500, "internal\nerror with\ttabs"))
    with pytest.raises(ModelError) as info:
        make(server.url, sleep=sleeps.append, max_retries=3).chat(REQUEST)
    assert len(server.seen) == 4 and len(sleeps) == 3
    assert all(0.005 <= s <= 0.05 for s in sleeps)
    assert sleeps[1] <= 0.02 + 1e-9 and sleeps[0] <= 0.01 + 1e-9  # base 0.01 s doubling, capped 0.05 s
    message = str(info.value)
    assert message.startswith(f"{kind}: HTTP 500") and "4 attempts" in message and "internal error" in message
    assert_one_line_without_key(info.value)


def test_read_timeout_retries_then_fails(kind, make, server):
    server.default = server.reply(200, ok_body(kind, "too late"), delay_s=0.6)
    t0 = time.perf_counter()
    with pytest.raises(ModelError) as info:
        make(server.url, timeout_s=0.2, max_retries=1).chat(REQUEST)
    assert time.perf_counter() - t0 < 1.5
    assert "read timeout" in str(info.value) and "2 attempts" in str(info.value)
    assert len(server.seen) == 2
    assert_one_line_without_key(info.value)


def test_garbage_body_is_one_line_model_error(kind, make, server):
    server.push(server.reply(200, b"<html>\x00\xff not json at all"))
    with pytest.raises(ModelError) as info:
        make(server.url).chat(REQUEST)
    assert "not a JSON object" in str(info.value)
    assert len(server.seen) == 1  # a well-delivered garbage reply is not retried
    assert_one_line_without_key(info.value)


def test_truncated_body_is_retried_then_fails(kind, make, server):
    # Content-Length promises more bytes than arrive: a torn reply, treated as a transport failure
    server.default = server.reply(200, b'{"message": {"content": "half', {"Content-Length": "500"})
    with pytest.raises(ModelError) as info:
        make(server.url, max_retries=1).chat(REQUEST)
    assert_one_line_without_key(info.value)
    assert len(server.seen) == 2


def test_wrong_shape_json_is_model_error(kind, make, server):
    server.push(server.reply(200, {"unexpected": True}))
    with pytest.raises(ModelError) as info:
        make(server.url).chat(REQUEST)
    assert str(info.value).startswith(f"{kind}: ")
    assert_one_line_without_key(info.value)


def test_connection_refused(kind, make, closed_port_url, sleeps):
    with pytest.raises(ModelError) as info:
        make(closed_port_url, sleep=sleeps.append).chat(REQUEST)
    assert "connection failed" in str(info.value) and "3 attempts" in str(info.value)
    assert len(sleeps) == 2
    assert_one_line_without_key(info.value)


def test_client_error_is_not_retried(kind, make, server, sleeps):
    echoed = FAKE_KEY if kind != "ollama" else "none"  # ollama has no key to protect
    server.default = server.reply(400, error_body(kind, 400, f"bad request; you sent key {echoed}"))
    with pytest.raises(ModelError) as info:
        make(server.url, sleep=sleeps.append).chat(REQUEST)
    assert len(server.seen) == 1 and sleeps == []
    assert "HTTP 400" in str(info.value) and "1 attempt " in str(info.value)
    assert_one_line_without_key(info.value)  # even a server echoing the key does not leak it


def test_rate_limit_spaces_requests(kind, make, server):
    server.default = server.reply(200, ok_body(kind, "x"))
    backend = make(server.url, rpm=600)  # one request per 0.1 s
    t0 = time.perf_counter()
    for _ in range(3):
        backend.chat(REQUEST)
    assert time.perf_counter() - t0 >= 0.19


def test_unknown_option_is_rejected(kind, make, server):
    from llmnav.errors import BackendSpecError

    with pytest.raises(BackendSpecError, match="tiemout_s"):
        make(server.url, tiemout_s=3)


def test_rate_limit_holds_across_threads(kind, make, server):
    from concurrent.futures import ThreadPoolExecutor

    server.default = server.reply(200, ok_body(kind, "x"))
    backend = make(server.url, rpm=600)  # one request start per 0.1 s, whichever thread sends it
    t0 = time.perf_counter()
    with ThreadPoolExecutor(2) as pool:
        texts = list(pool.map(lambda _: backend.chat(REQUEST).text, range(4)))
    assert texts == ["x"] * 4
    assert time.perf_counter() - t0 >= 0.29
