"""Ollama backend: the /api/chat request it sends and the reply it reads, against a loopback server."""

from __future__ import annotations

import base64

import pytest

from llmnav.backends.base import ChatRequest, Image, Message
from llmnav.backends.ollama import OllamaBackend, model_listed, ollama_host

JPEG = Image(base64.b64encode(b"\xff\xd8\xff\xe0fake-jpeg").decode())
SCHEMA = {"type": "object", "properties": {"x": {"type": "number"}}, "required": ["x"]}


def reply(text: str) -> dict:
    return {
        "model": "llava:7b",
        "created_at": "2026-01-01T00:00:00Z",
        "message": {"role": "assistant", "content": text},
        "done": True,
        "done_reason": "stop",
        "total_duration": 2_500_000_000,
        "load_duration": 100_000_000,
        "prompt_eval_count": 42,
        "eval_count": 7,
    }


def test_request_fields_and_reply(server):
    server.push(server.reply(200, reply('{"x": 1.5}')))
    backend = OllamaBackend("llava:7b", base_url=server.url, num_ctx=4096, keep_alive="30m")
    request = ChatRequest(
        (Message("system", "You drive a robot."), Message("user", "What now?", (JPEG,))),
        json_schema=SCHEMA,
        temperature=0.2,
        max_tokens=128,
        seed=7,
    )
    result = backend.chat(request)

    seen = server.seen[0]
    assert (seen.method, seen.path) == ("POST", "/api/chat")
    body = seen.body
    assert body["model"] == "llava:7b" and body["stream"] is False
    assert body["format"] == SCHEMA
    assert body["keep_alive"] == "30m"
    assert body["options"] == {"temperature": 0.2, "num_predict": 128, "seed": 7, "num_ctx": 4096}
    assert body["messages"][0] == {"role": "system", "content": "You drive a robot."}
    assert body["messages"][1]["images"] == [JPEG.jpeg_b64]
    assert "authorization" not in seen.headers

    assert result.text == '{"x": 1.5}'
    assert (result.prompt_tokens, result.completion_tokens) == (42, 7)
    assert result.model == "llava:7b"
    assert result.meta["total_duration_s"] == pytest.approx(2.5)
    assert result.meta["done_reason"] == "stop"


def test_no_schema_asks_for_json_and_no_seed_is_omitted(server):
    server.push(server.reply(200, reply("{}")))
    OllamaBackend(base_url=server.url).chat(ChatRequest((Message("user", "hi"),)))
    body = server.seen[0].body
    assert body["model"] == "llama3.1"
    assert body["format"] == "json"
    assert "seed" not in body["options"] and "num_ctx" not in body["options"]


def test_host_from_environment(monkeypatch):
    monkeypatch.setenv("OLLAMA_HOST", "0.0.0.0:11500")
    assert ollama_host() == "http://127.0.0.1:11500"
    monkeypatch.delenv("OLLAMA_HOST")
    assert ollama_host() == "http://127.0.0.1:11434"
    assert ollama_host("http://gpu-box:11434/") == "http://gpu-box:11434"


def test_status_reachable_and_model_listed(server, monkeypatch):
    monkeypatch.setenv("OLLAMA_HOST", server.url)
    tags = {"models": [{"name": "llama3.1:latest"}, {"name": "qwen2.5:0.5b"}]}
    server.default = server.reply(200, tags)
    ok = OllamaBackend.status("llama3.1")
    assert ok.ready and server.url in ok.detail
    assert server.seen[-1].path == "/api/tags" and server.seen[-1].method == "GET"
    missing = OllamaBackend.status("mistral")
    assert not missing.ready and "ollama pull mistral" in missing.detail
    assert OllamaBackend.status("qwen2.5:0.5b").ready


def test_status_without_server(closed_port_url, monkeypatch):
    monkeypatch.setenv("OLLAMA_HOST", closed_port_url)
    status = OllamaBackend.status()
    assert not status.ready and "no server" in status.detail and "refused" in status.detail.lower()


def test_model_listed_tags():
    assert model_listed("llama3.1", ["llama3.1:latest"])
    assert not model_listed("llama3.1", ["llama3.1:8b"])
    assert model_listed("llama3.1:8b", ["llama3.1:8b"])
