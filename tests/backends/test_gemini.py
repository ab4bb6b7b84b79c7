"""Gemini backend: generateContent request, schema conversion, key handling, against a loopback server."""

from __future__ import annotations

import base64
import json
from enum import StrEnum

import pytest
from pydantic import BaseModel, Field

from llmnav.backends.base import ChatRequest, Image, Message
from llmnav.backends.gemini import GeminiBackend, to_gemini_schema
from llmnav.errors import MissingKeyError, ModelError

KEY = "AIzaFAKE-gemini-key-000111222333"
JPEG = Image(base64.b64encode(b"\xff\xd8\xff\xe0gemini-jpeg").decode())


class Command(StrEnum):
    FRONT = "FRONT"
    ROTATE_LEFT = "ROTATE_LEFT"


class Spec(BaseModel):
    command: Command
    parameters: float = Field(gt=0, le=5)


class Step(BaseModel):
    goal: str
    note: str | None = None
    action: Spec = Field(description="what to do")


OK = {
    "candidates": [
        {"content": {"role": "model", "parts": [{"text": '{"a"'}, {"text": ": 1}"}]}, "finishReason": "STOP"}
    ],
    "usageMetadata": {"promptTokenCount": 11, "candidatesTokenCount": 5, "totalTokenCount": 16},
    "modelVersion": "gemini-2.0-flash-001",
}


@pytest.fixture
def keyed(monkeypatch):
    monkeypatch.delenv("GOOGLE_API_KEY", raising=False)
    monkeypatch.setenv("GEMINI_API_KEY", KEY)


def test_request_fields_and_reply(server, keyed):
    server.push(server.reply(200, OK))
    backend = GeminiBackend("gemini-1.5-pro", base_url=server.url)
    request = ChatRequest(
        (
            Message("system", "Be a careful driver."),
            Message("user", "Look:", (JPEG,)),
            Message("assistant", '{"a": 0}'),
            Message("user", "Again."),
        ),
        json_schema=Step.model_json_schema(),
        temperature=0.3,
        max_tokens=99,
        seed=5,
    )
    result = backend.chat(request)

    seen = server.seen[0]
    assert seen.path == "/v1beta/models/gemini-1.5-pro:generateContent"
    assert seen.headers["x-goog-api-key"] == KEY
    assert KEY not in seen.path
    body = seen.body
    assert body["systemInstruction"] == {"parts": [{"text": "Be a careful driver."}]}
    assert [c["role"] for c in body["contents"]] == ["user", "model", "user"]
    assert body["contents"][0]["parts"] == [
        {"text": "Look:"},
        {"inline_data": {"mime_type": "image/jpeg", "data": JPEG.jpeg_b64}},
    ]
    config = body["generationConfig"]
    assert config["temperature"] == 0.3 and config["maxOutputTokens"] == 99 and config["seed"] == 5
    assert config["responseMimeType"] == "application/json"
    assert config["responseSchema"] == to_gemini_schema(Step.model_json_schema())

    assert result.text == '{"a": 1}'
    assert (result.prompt_tokens, result.completion_tokens) == (11, 5)
    assert result.model == "gemini-2.0-flash-001" and result.meta["finish_reason"] == "STOP"


def test_schema_conversion_keeps_only_the_openapi_subset():
    converted = to_gemini_schema(Step.model_json_schema())
    text = json.dumps(converted)
    for banned in (
        "$ref",
        "$defs",
        "title",
        "additionalProperties",
        "exclusiveMinimum",
        "allOf",
        '"default"',
    ):
        assert banned not in text, banned
    assert converted["type"] == "OBJECT" and converted["required"] == ["goal", "action"]
    assert converted["propertyOrdering"] == ["goal", "note", "action"]
    assert converted["properties"]["note"] == {"nullable": True, "type": "STRING"}
    action = converted["properties"]["action"]
    assert action["description"] == "what to do" and action["type"] == "OBJECT"
    assert action["properties"]["command"] == {"type": "STRING", "enum": ["FRONT", "ROTATE_LEFT"]}
    assert action["properties"]["parameters"] == {"type": "NUMBER", "minimum": 0, "maximum": 5}


def test_schema_conversion_arrays_and_type_lists():
    schema = {
        "type": "array",
        "items": {
            "type": "object",
            "additionalProperties": False,
            "properties": {"x": {"type": ["number", "null"]}},
        },
    }
    out = to_gemini_schema(schema)
    assert out["type"] == "ARRAY"
    assert out["items"]["properties"]["x"] == {"nullable": True, "type": "NUMBER"}
    assert "additionalProperties" not in out["items"]


def test_missing_key_names_the_variable(monkeypatch):
    monkeypatch.delenv("GEMINI_API_KEY", raising=False)
    monkeypatch.delenv("GOOGLE_API_KEY", raising=False)
    with pytest.raises(MissingKeyError, match="GEMINI_API_KEY"):
        GeminiBackend()
    status = GeminiBackend.status()
    assert not status.ready and "GEMINI_API_KEY" in status.detail


def test_google_api_key_fallback_and_env_base_url(server, monkeypatch):
    monkeypatch.delenv("GEMINI_API_KEY", raising=False)
    monkeypatch.setenv("GOOGLE_API_KEY", KEY)
    monkeypatch.setenv("LLMNAV_GEMINI_BASE_URL", server.url)
    server.push(server.reply(200, OK))
    backend = GeminiBackend()
    backend.chat(ChatRequest((Message("user", "hi"),)))
    assert server.seen[0].path == "/v1beta/models/gemini-2.0-flash:generateContent"
    assert server.seen[0].headers["x-goog-api-key"] == KEY
    assert "responseSchema" not in server.seen[0].body["generationConfig"]
    assert GeminiBackend.status().ready and "GOOGLE_API_KEY" in GeminiBackend.status().detail
    assert KEY not in repr(backend) and KEY not in repr(backend.client) and KEY not in backend.spec


def test_blocked_prompt_and_empty_candidate(server, keyed):
    server.push(
        server.reply(200, {"promptFeedback": {"blockReason": "SAFETY"}}),
        server.reply(200, {"candidates": [{"finishReason": "MAX_TOKENS", "content": {"parts": []}}]}),
    )
    backend = GeminiBackend(base_url=server.url)
    with pytest.raises(ModelError, match=r"prompt blocked \(SAFETY\)"):
        backend.chat(ChatRequest((Message("user", "hi"),)))
    with pytest.raises(ModelError, match="MAX_TOKENS"):
        backend.chat(ChatRequest((Message("user", "hi"),)))


def test_gemini_error_envelope_reason(server, keyed):
    server.default = server.reply(
        403,
        {
            "error": {
                "code": 403,
                "message": f"API key not valid. Please pass a valid API key. ({KEY})",
                "status": "PERMISSION_DENIED",
            }
        },
    )
    with pytest.raises(ModelError) as info:
        GeminiBackend(base_url=server.url, max_retries=0).chat(ChatRequest((Message("user", "hi"),)))
    assert "HTTP 403" in str(info.value) and "API key not valid" in str(info.value)
    assert KEY not in str(info.value)
