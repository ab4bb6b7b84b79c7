"""OpenAI-compatible backend: chat/completions request, base URL resolution, key handling."""

from __future__ import annotations

import base64

import pytest

from llmnav.backends.base import ChatRequest, Image, Message
from llmnav.backends.openai import OpenAIBackend, split_arg
from llmnav.errors import MissingKeyError, ModelError

KEY = "sk-FAKE-openai-key-9876543210"
JPEG = Image(base64.b64encode(b"\xff\xd8\xff\xe0openai-jpeg").decode())
SCHEMA = {"type": "object", "properties": {"option": {"type": "integer"}}, "required": ["option"]}
OK = {
    "id": "c1",
    "model": "qwen-local",
    "choices": [
        {"index": 0, "finish_reason": "stop", "message": {"role": "assistant", "content": '{"option": 2}'}}
    ],
    "usage": {"prompt_tokens": 20, "completion_tokens": 6, "total_tokens": 26},
}


def test_request_fields_and_reply(server, monkeypatch):
    monkeypatch.setenv("OPENAI_API_KEY", KEY)
    server.push(server.reply(200, OK))
    backend = OpenAIBackend(f"qwen-local@{server.url}/v1", strict=True)
    request = ChatRequest(
        (Message("system", "sys"), Message("user", "see", (JPEG,)), Message("assistant", "{}")),
        json_schema=SCHEMA,
        temperature=0.1,
        max_tokens=64,
        seed=3,
    )
    result = backend.chat(request)

    seen = server.seen[0]
    assert seen.path == "/v1/chat/completions"
    assert seen.headers["authorization"] == f"Bearer {KEY}"
    body = seen.body
    assert body["model"] == "qwen-local"
    assert body["messages"][0] == {"role": "system", "content": "sys"}
    assert body["messages"][1]["content"] == [
        {"type": "text", "text": "see"},
        {"type": "image_url", "image_url": {"url": f"data:image/jpeg;base64,{JPEG.jpeg_b64}"}},
    ]
    assert body["messages"][2] == {"role": "assistant", "content": "{}"}
    assert body["response_format"] == {
        "type": "json_schema",
        "json_schema": {"name": "answer", "schema": SCHEMA, "strict": True},
    }
    assert (body["temperature"], body["max_tokens"], body["seed"]) == (0.1, 64, 3)

    assert result.text == '{"option": 2}'
    assert (result.prompt_tokens, result.completion_tokens) == (20, 6)
    assert result.meta["finish_reason"] == "stop"
    assert KEY not in repr(backend) and KEY not in backend.spec and KEY not in repr(backend.client)


def test_local_server_needs_no_key(server, monkeypatch):
    monkeypatch.delenv("OPENAI_API_KEY", raising=False)
    monkeypatch.setenv("OPENAI_BASE_URL", server.url + "/v1/")
    server.push(server.reply(200, OK))
    backend = OpenAIBackend(max_tokens_field="max_completion_tokens")
    backend.chat(ChatRequest((Message("user", "hi"),)))
    body = server.seen[0].body
    assert "authorization" not in server.seen[0].headers
    assert body["model"] == "gpt-4o-mini" and body["response_format"] == {"type": "json_object"}
    assert body["max_completion_tokens"] == 512 and "max_tokens" not in body and "seed" not in body


def test_official_api_without_key_is_missing_key(monkeypatch):
    monkeypatch.delenv("OPENAI_API_KEY", raising=False)
    monkeypatch.delenv("OPENAI_BASE_URL", raising=False)
    with pytest.raises(MissingKeyError, match="OPENAI_API_KEY"):
        OpenAIBackend("gpt-4o")
    assert not OpenAIBackend.status("gpt-4o").ready


def test_status_probes_models(server, closed_port_url, monkeypatch):
    monkeypatch.setenv("OPENAI_API_KEY", KEY)
    server.default = server.reply(200, {"data": [{"id": "qwen-local"}]})
    status = OpenAIBackend.status(f"qwen-local@{server.url}/v1")
    assert status.ready and server.seen[-1].path == "/v1/models"
    assert server.seen[-1].headers["authorization"] == f"Bearer {KEY}"
    down = OpenAIBackend.status(f"x@{closed_port_url}/v1")
    assert not down.ready and "refused" in down.detail.lower() and KEY not in down.detail


def test_refusal_is_model_error(server, monkeypatch):
    monkeypatch.delenv("OPENAI_API_KEY", raising=False)
    refusal = {"choices": [{"message": {"role": "assistant", "content": None, "refusal": "I can't"}}]}
    server.push(server.reply(200, refusal))
    with pytest.raises(ModelError, match="refused: I can't"):
        OpenAIBackend(f"m@{server.url}").chat(ChatRequest((Message("user", "hi"),)))


def test_split_arg():
    assert split_arg("gpt-4o@http://h:8080/v1") == ("gpt-4o", "http://h:8080/v1")
    assert split_arg("@http://h/v1") == ("gpt-4o-mini", "http://h/v1")
    assert split_arg(None) == ("gpt-4o-mini", None)
