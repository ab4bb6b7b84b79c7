"""Gemini backend: `gemini[:MODEL]` → POST {base}/v1beta/models/{MODEL}:generateContent.

Key from `GEMINI_API_KEY` (or `GOOGLE_API_KEY`), sent as the `x-goog-api-key` header, never in the URL.
System messages become `systemInstruction`; assistant turns have role `model`; images are inline JPEG.
Gemini's `responseSchema` accepts only a subset of OpenAPI 3.0, so `to_gemini_schema` rewrites a pydantic
JSON Schema into it: `$ref` inlined, `anyOf [X, null]` → nullable X, exclusive bounds → inclusive ones,
unsupported keywords (title, additionalProperties, $defs, default, ...) dropped.
"""

from __future__ import annotations

import os
from typing import Any, ClassVar

from pydantic import Field

from llmnav.backends.base import BackendStatus, ChatRequest, ChatResult
from llmnav.backends.http import HttpBackend, HttpOptions, JsonHttpClient, normalise_url
from llmnav.backends.reply import obj, seq, text_or_none, usage_counts
from llmnav.errors import BackendSpecError, MissingKeyError, ModelError, one_line

DEFAULT_BASE_URL = "https://generativelanguage.googleapis.com"
KEY_VARIABLES = ("GEMINI_API_KEY", "GOOGLE_API_KEY")
BASE_URL_VARIABLE = "LLMNAV_GEMINI_BASE_URL"

# Keywords Gemini's Schema object understands; everything else is dropped.
_KEPT = frozenset(
    {
        "type",
        "format",
        "description",
        "nullable",
        "enum",
        "items",
        "properties",
        "required",
        "minItems",
        "maxItems",
        "minimum",
        "maximum",
        "anyOf",
        "propertyOrdering",
    }
)
_TYPES = {
    "string": "STRING",
    "number": "NUMBER",
    "integer": "INTEGER",
    "boolean": "BOOLEAN",
    "array": "ARRAY",
    "object": "OBJECT",
}
_MAX_REF_DEPTH = 32  # recursive schemas cannot be inlined; stop with a clear error


class GeminiOptions(HttpOptions):
    """Gemini knobs on top of the shared HTTP options."""

    timeout_s: float = Field(default=90.0, gt=0)  # [s]
    json_mode: bool = True  # responseMimeType application/json even without a schema


def api_key() -> tuple[str | None, str | None]:
    """The API key and the variable it came from (None, None when neither is set)."""
    for variable in KEY_VARIABLES:
        value = os.environ.get(variable, "").strip()
        if value:
            return value, variable
    return None, None


def to_gemini_schema(schema: dict[str, Any]) -> dict[str, Any]:
    """Rewrite a JSON Schema (as pydantic emits it) into Gemini's OpenAPI subset."""
    defs = {**schema.get("definitions", {}), **schema.get("$defs", {})}
    return _convert(schema, defs, 0)


def _resolve(ref: str, defs: dict[str, Any]) -> dict[str, Any]:
    name = ref.rsplit("/", 1)[-1]
    if not ref.startswith(("#/$defs/", "#/definitions/")) or name not in defs:
        raise BackendSpecError(f"gemini: cannot inline schema reference {ref!r}")
    return defs[name]


def _convert(node: Any, defs: dict[str, Any], depth: int) -> Any:
    if not isinstance(node, dict):
        return node
    if depth > _MAX_REF_DEPTH:
        raise BackendSpecError("gemini: the answer schema is recursive; Gemini's responseSchema cannot express it")
    if "$ref" in node:  # siblings of $ref (description) win over the referenced schema's
        merged = {**_resolve(node["$ref"], defs), **{k: v for k, v in node.items() if k != "$ref"}}
        return _convert(merged, defs, depth + 1)
    if "allOf" in node and len(node["allOf"]) == 1:  # pydantic wraps a described $ref this way
        merged = {**node["allOf"][0], **{k: v for k, v in node.items() if k != "allOf"}}
        return _convert(merged, defs, depth + 1)
    out: dict[str, Any] = {}
    variants = node.get("anyOf") or node.get("oneOf")
    if variants:
        non_null = [v for v in variants if not (isinstance(v, dict) and v.get("type") == "null")]
        if len(non_null) < len(variants):
            out["nullable"] = True
        if len(non_null) == 1:
            inner = _convert(non_null[0], defs, depth + 1)
            out.update({k: v for k, v in inner.items() if k != "nullable" or v})
        else:
            out["anyOf"] = [_convert(v, defs, depth + 1) for v in non_null]
    kind = node.get("type")
    if isinstance(kind, list):  # ["number", "null"]
        if "null" in kind:
            out["nullable"] = True
        kinds = [k for k in kind if k != "null"]
        kind = kinds[0] if len(kinds) == 1 else None
    if isinstance(kind, str) and kind in _TYPES:
        out["type"] = _TYPES[kind]
    if "const" in node:
        out["enum"] = [node["const"]]
    if "exclusiveMinimum" in node and isinstance(node["exclusiveMinimum"], (int, float)):
        out["minimum"] = node["exclusiveMinimum"]  # nearest bound Gemini can state; the guard is exact
    if "exclusiveMaximum" in node and isinstance(node["exclusiveMaximum"], (int, float)):
        out["maximum"] = node["exclusiveMaximum"]
    for key, value in node.items():
        if key not in _KEPT or key in out or key == "anyOf":
            continue
        if key == "properties":
            out[key] = {name: _convert(sub, defs, depth + 1) for name, sub in value.items()}
        elif key == "items":
            out[key] = _convert(value, defs, depth + 1)
        elif key == "enum":
            out[key] = [str(v) for v in value]  # Gemini enums are strings
            out.setdefault("type", "STRING")
        else:
            out[key] = value
    if out.get("type") == "OBJECT" and "properties" in out and "propertyOrdering" not in out:
        out["propertyOrdering"] = list(out["properties"])  # answer fields in the schema's order
    return out


class GeminiBackend(HttpBackend):
    """Google Gemini through the Generative Language REST API."""

    name = "gemini"
    default_arg = "gemini-2.0-flash"
    description = "Google Gemini API (GEMINI_API_KEY)"
    example = "gemini:gemini-2.0-flash"
    multimodal = True
    options_model: ClassVar[type[HttpOptions]] = GeminiOptions
    # the API's model list (one page holds them all; names come as `models/<id>`)
    models_path: ClassVar[str] = "/v1beta/models?pageSize=1000"

    def __init__(self, arg: str | None = None, **options: Any) -> None:
        super().__init__(arg, **options)
        key, _ = api_key()
        if key is None:
            raise MissingKeyError("gemini needs an API key: set GEMINI_API_KEY (or GOOGLE_API_KEY)")
        self.__key = key  # name-mangled and never in repr/spec/messages

    def _make_client(self) -> JsonHttpClient:
        base = self.settings.base_url or os.environ.get(BASE_URL_VARIABLE) or DEFAULT_BASE_URL
        return JsonHttpClient(
            self.name,
            normalise_url(base),
            self.settings,
            headers={"x-goog-api-key": self.__key},
            secrets=(self.__key,),
        )

    def listed_models(self, data: dict[str, Any]) -> list[str]:
        """Model ids in a `models.list` reply (`models/gemini-2.0-flash` → `gemini-2.0-flash`)."""
        models = data.get("models")
        entries = models if isinstance(models, list) else []
        names = [m.get("name") for m in entries if isinstance(m, dict)]
        return [name.removeprefix("models/") for name in names if isinstance(name, str)]

    def build_body(self, request: ChatRequest) -> dict[str, Any]:
        """The generateContent body for a request."""
        system = [m.text for m in request.messages if m.role == "system"]
        contents: list[dict[str, Any]] = []
        for message in request.messages:
            if message.role == "system":
                continue
            parts: list[dict[str, Any]] = []
            if message.text:
                parts.append({"text": message.text})
            for img in message.images:
                parts.append({"inline_data": {"mime_type": "image/jpeg", "data": img.jpeg_b64}})
            if not parts:
                parts.append({"text": ""})
            contents.append({"role": "model" if message.role == "assistant" else "user", "parts": parts})
        config: dict[str, Any] = {"temperature": request.temperature, "maxOutputTokens": request.max_tokens}
        if request.seed is not None:
            config["seed"] = request.seed
        assert isinstance(self.settings, GeminiOptions)
        if request.json_schema is not None or self.settings.json_mode:
            config["responseMimeType"] = "application/json"
        if request.json_schema is not None:
            config["responseSchema"] = to_gemini_schema(request.json_schema)
        body: dict[str, Any] = {"contents": contents, "generationConfig": config}
        if system:
            body["systemInstruction"] = {"parts": [{"text": "\n\n".join(system)}]}
        return body

    def chat(self, request: ChatRequest) -> ChatResult:
        """One generateContent call."""
        reply = self.client.post(f"/v1beta/models/{self.arg}:generateContent", self.build_body(request))
        data = reply.data
        candidates = seq(data.get("candidates"), "gemini: reply's candidates")
        if not candidates:
            feedback = obj(data.get("promptFeedback"), "gemini: reply's promptFeedback")
            blocked = text_or_none(feedback.get("blockReason"), "gemini: reply's promptFeedback.blockReason")
            why = f"prompt blocked ({one_line(blocked, 80)})" if blocked else "reply has no candidates"
            raise ModelError(f"gemini: {why}")
        first = obj(candidates[0], "gemini: reply's candidates[0]")
        content = obj(first.get("content"), "gemini: reply's candidates[0].content")
        parts = seq(content.get("parts"), "gemini: reply's candidates[0].content.parts")
        texts = [p["text"] for p in parts if isinstance(p, dict) and isinstance(p.get("text"), str)]
        finish = text_or_none(first.get("finishReason"), "gemini: reply's candidates[0].finishReason")
        if not texts:
            raise ModelError(f"gemini: reply has no text (finishReason {finish and one_line(finish, 40)})")
        prompt_tokens, completion_tokens = usage_counts(
            data.get("usageMetadata"), "gemini: reply's usageMetadata", "promptTokenCount", "candidatesTokenCount"
        )
        return ChatResult(
            text="".join(texts),
            latency_s=reply.elapsed_s,
            model=text_or_none(data.get("modelVersion"), "gemini: reply's modelVersion") or str(self.arg),
            prompt_tokens=prompt_tokens,
            completion_tokens=completion_tokens,
            meta={"attempts": reply.attempts, "cache": reply.cache, "finish_reason": finish},
        )

    @classmethod
    def status(cls, arg: str | None = None) -> BackendStatus:
        """Ready when a key is set (no network call: it would spend quota)."""
        _, variable = api_key()
        if variable is None:
            return BackendStatus(False, "GEMINI_API_KEY (or GOOGLE_API_KEY) not set")
        return BackendStatus(True, f"key from {variable}")
