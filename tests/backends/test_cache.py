"""The reply cache (`--cache DIR`): hits send nothing, torn and foreign entries are misses, keys never stored.

Every test talks to the loopback `server` (tests/conftest.py) through llmnav's own openai, ollama and
gemini backends; the server counts what reaches it.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from llmnav.backends.base import ChatRequest, Message, get_backend
from llmnav.backends.cache import CACHE_FORMAT, ReplyCache

KEY = "sk-cache-test-secret-5a6b7c8d"
OPENAI_REPLY = {
    "choices": [{"message": {"role": "assistant", "content": '{"ok": true}'}, "finish_reason": "stop"}],
    "model": "m",
    "usage": {"prompt_tokens": 120, "completion_tokens": 7},
}


def _request(text: str = "Where is the door?", seed: int | None = 3, temperature: float = 0.0) -> ChatRequest:
    return ChatRequest((Message("user", text),), temperature=temperature, max_tokens=32, seed=seed)


def _openai(server: Any, cache: ReplyCache, fast: dict[str, Any], model: str = "m") -> Any:
    backend = get_backend(f"openai:{model}@{server.url}/v1", **fast)
    backend.use_cache(cache)
    return backend


def _posts(server: Any) -> int:
    return sum(1 for seen in server.seen if seen.method == "POST")


def test_a_repeated_request_is_served_from_the_cache(server, tmp_path, fast):
    server.default = server.reply(200, OPENAI_REPLY)
    cache = ReplyCache(tmp_path / "cache")
    first = _openai(server, cache, fast).chat(_request())
    assert (first.meta["cache"], _posts(server)) == ("miss", 1)
    second = _openai(server, cache, fast).chat(_request())  # a new backend object: the cache is on disk
    assert (second.meta["cache"], _posts(server)) == ("hit", 1)
    assert (second.text, second.prompt_tokens, second.completion_tokens) == (first.text, 120, 7)


@pytest.mark.parametrize(
    "change",
    [
        {"text": "Where is the window?"},  # the request
        {"seed": 4},  # the seed
        {"temperature": 0.7},  # a sampling setting
    ],
)
def test_each_part_of_the_key_tells_requests_apart(server, tmp_path, fast, change):
    server.default = server.reply(200, OPENAI_REPLY)
    cache = ReplyCache(tmp_path / "cache")
    _openai(server, cache, fast).chat(_request())
    assert _openai(server, cache, fast).chat(_request(**change)).meta["cache"] == "miss"
    assert _posts(server) == 2


def test_model_and_server_are_part_of_the_key(server, tmp_path, fast):
    server.default = server.reply(200, OPENAI_REPLY)
    cache = ReplyCache(tmp_path / "cache")
    _openai(server, cache, fast).chat(_request())
    assert _openai(server, cache, fast, model="other").chat(_request()).meta["cache"] == "miss"
    other = get_backend(f"openai:m@{server.url.replace('127.0.0.1', 'localhost')}/v1", **fast)
    other.use_cache(cache)
    assert other.chat(_request()).meta["cache"] == "miss"
    assert _posts(server) == 3


def _only_entry(cache: ReplyCache) -> Path:
    files = [p for p in cache.root.rglob("*.json")]
    assert len(files) == 1
    return files[0]


@pytest.mark.parametrize(
    "damage",
    [
        lambda text: text[: len(text) // 2],  # torn: half an entry
        lambda text: "",  # empty
        lambda text: "\x00\xff garbage",  # not JSON
        lambda text: json.dumps({**json.loads(text), "format": CACHE_FORMAT + 1}),  # another format
        lambda text: json.dumps({**json.loads(text), "reply": "not an object"}),  # wrong shape
        lambda text: json.dumps({**json.loads(text), "key": "0" * 64}),  # another request's entry
    ],
    ids=["torn", "empty", "garbage", "other-format", "wrong-shape", "other-key"],
)
def test_a_damaged_or_foreign_entry_is_a_miss_and_is_replaced(server, tmp_path, fast, damage):
    server.default = server.reply(200, OPENAI_REPLY)
    cache = ReplyCache(tmp_path / "cache")
    _openai(server, cache, fast).chat(_request())
    entry = _only_entry(cache)
    entry.write_text(damage(entry.read_text()), errors="surrogateescape")
    again = _openai(server, cache, fast).chat(_request())
    assert (again.meta["cache"], again.text, _posts(server)) == ("miss", '{"ok": true}', 2)
    assert json.loads(entry.read_text())["format"] == CACHE_FORMAT  # rewritten whole
    assert _openai(server, cache, fast).chat(_request()).meta["cache"] == "hit"


def test_no_temporary_file_is_left_and_errors_are_not_cached(server, tmp_path, fast):
    server.push(server.reply(400, {"error": {"message": "bad request"}}))
    server.default = server.reply(200, OPENAI_REPLY)
    cache = ReplyCache(tmp_path / "cache")
    with pytest.raises(Exception, match="bad request"):
        _openai(server, cache, fast).chat(_request())
    assert list(cache.root.rglob("*")) == []
    _openai(server, cache, fast).chat(_request())
    assert [p.suffix for p in cache.root.rglob("*") if p.is_file()] == [".json"]


def test_keys_never_reach_the_cache(server, tmp_path, fast, monkeypatch):
    monkeypatch.setenv("OPENAI_API_KEY", KEY)
    monkeypatch.setenv("GEMINI_API_KEY", KEY)
    monkeypatch.setenv("OLLAMA_API_KEY", KEY)
    monkeypatch.setenv("OLLAMA_HOST", server.url)
    monkeypatch.setenv("LLMNAV_GEMINI_BASE_URL", server.url)
    gemini_reply = {
        "candidates": [{"content": {"parts": [{"text": '{"ok": true}'}]}, "finishReason": "STOP"}],
        "usageMetadata": {"promptTokenCount": 5, "candidatesTokenCount": 2},
    }
    ollama_reply = {"message": {"role": "assistant", "content": '{"ok": true}'}, "done_reason": "stop"}

    def answer(seen: Any) -> Any:
        if "generateContent" in seen.path:
            return server.reply(200, gemini_reply)
        return server.reply(200, ollama_reply if seen.path == "/api/chat" else OPENAI_REPLY)

    server.default = answer
    cache = ReplyCache(tmp_path / "cache")
    user_url = server.url.replace("http://", f"http://user:{KEY}x@")  # credentials in the URL too
    for spec in ("openai:m@" + server.url + "/v1", "openai:m@" + user_url + "/v1", "gemini:g", "ollama:o"):
        backend = get_backend(spec, **fast)
        backend.use_cache(cache)
        assert backend.chat(_request()).meta["cache"] == "miss"
        assert backend.chat(_request()).meta["cache"] == "hit"
    assert _posts(server) == 4
    assert all(seen.headers.get("authorization") or seen.headers.get("x-goog-api-key") for seen in server.seen)
    stored = b"".join(p.read_bytes() for p in cache.root.rglob("*") if p.is_file())
    assert len(list(cache.root.rglob("*.json"))) == 4
    assert KEY.encode() not in stored and b"user:" not in stored


def test_a_reply_echoing_the_key_is_not_stored(server, tmp_path, fast, monkeypatch):
    monkeypatch.setenv("OPENAI_API_KEY", KEY)
    echo = {**OPENAI_REPLY, "choices": [{"message": {"role": "assistant", "content": f"your key is {KEY}"}}]}
    server.default = server.reply(200, echo)
    cache = ReplyCache(tmp_path / "cache")
    assert _openai(server, cache, fast).chat(_request()).meta["cache"] == "miss"
    assert list(cache.root.rglob("*.json")) == []


def test_a_cache_that_is_a_file_is_bad_input(tmp_path):
    from llmnav.errors import BadInputError

    (tmp_path / "f").write_text("x")
    with pytest.raises(BadInputError, match="--cache"):
        ReplyCache(tmp_path / "f")
