"""Ollama backend: `ollama[:MODEL]` → POST {OLLAMA_HOST}/api/chat, non-streaming.

The answer's JSON Schema goes in `format` (Ollama turns it into a grammar), images as a base64 list on
the message, sampling knobs in `options`. Server: `OLLAMA_HOST` or http://127.0.0.1:11434.
`OLLAMA_API_KEY`, when set, is sent as a Bearer token (an Ollama behind an authenticating proxy).
"""

from __future__ import annotations

import os
from typing import Any, ClassVar

from pydantic import Field

from llmnav.backends.base import BackendStatus, ChatRequest, ChatResult
from llmnav.backends.http import (
    HttpBackend,
    HttpOptions,
    JsonHttpClient,
    bearer,
    normalise_url,
    probe,
    short_reason,
)
from llmnav.backends.reply import duration, text_or_none, token_count
from llmnav.errors import ModelError

DEFAULT_HOST = "http://127.0.0.1:11434"
KEY_VARIABLE = "OLLAMA_API_KEY"
NS = 1e-9  # [s] per nanosecond: Ollama reports durations in ns


class OllamaOptions(HttpOptions):
    """Ollama knobs on top of the shared HTTP options."""

    timeout_s: float = Field(default=300.0, gt=0)  # [s] a cold model load on CPU can take minutes
    keep_alive: str | int | None = "10m"  # how long Ollama keeps the model loaded between calls
    num_ctx: int | None = Field(default=None, ge=256)  # context window [tokens]; None = server default
    json_mode: bool = True  # `format: "json"` when a request carries no schema


def ollama_host(override: str | None = None) -> str:
    """The server base URL: option, else `OLLAMA_HOST`, else the local default."""
    return normalise_url(override or os.environ.get("OLLAMA_HOST") or DEFAULT_HOST)


def _api_key() -> str | None:
    return os.environ.get(KEY_VARIABLE, "").strip() or None


def model_listed(model: str, names: list[str]) -> bool:
    """Whether `/api/tags` lists the model; an untagged name means `:latest`."""
    wanted = model if ":" in model else f"{model}:latest"
    return any(name in (model, wanted) for name in names)


class OllamaBackend(HttpBackend):
    """A model served by Ollama (local or remote)."""

    name = "ollama"
    default_arg = "llama3.1"
    description = "Ollama server (OLLAMA_HOST), JSON Schema as format"
    example = "ollama:llama3.2-vision"
    multimodal = True
    options_model: ClassVar[type[HttpOptions]] = OllamaOptions
    chat_path: ClassVar[str] = "/api/chat"
    models_path: ClassVar[str] = "/api/tags"

    def __init__(self, arg: str | None = None, **options: Any) -> None:
        super().__init__(arg, **options)
        ollama_host(self.settings.base_url)  # a malformed OLLAMA_HOST is bad input now, not an aborted run
        self.__key = _api_key()  # name-mangled and never in repr/spec/messages

    def _make_client(self) -> JsonHttpClient:
        headers, secrets = bearer(self.__key)
        return JsonHttpClient(
            self.name, ollama_host(self.settings.base_url), self.settings, headers=headers, secrets=secrets
        )

    def listed_models(self, data: dict[str, Any]) -> list[str]:
        """Model names in an /api/tags reply."""
        return [m["name"] for m in data.get("models") or [] if isinstance(m, dict) and isinstance(m.get("name"), str)]

    def model_present(self, names: list[str]) -> bool:
        """Whether the model is pulled (an untagged name means `:latest`)."""
        return model_listed(self.model_name, names)

    def build_body(self, request: ChatRequest) -> dict[str, Any]:
        """The /api/chat body for a request."""
        settings = self.settings
        assert isinstance(settings, OllamaOptions)
        messages: list[dict[str, Any]] = []
        for message in request.messages:
            entry: dict[str, Any] = {"role": message.role, "content": message.text}
            if message.images:
                entry["images"] = [img.jpeg_b64 for img in message.images]
            messages.append(entry)
        options: dict[str, Any] = {"temperature": request.temperature, "num_predict": request.max_tokens}
        if request.seed is not None:
            options["seed"] = request.seed
        if settings.num_ctx is not None:
            options["num_ctx"] = settings.num_ctx
        body: dict[str, Any] = {"model": self.arg, "messages": messages, "stream": False, "options": options}
        if request.json_schema is not None:
            body["format"] = request.json_schema
        elif settings.json_mode:
            body["format"] = "json"
        if settings.keep_alive is not None:
            body["keep_alive"] = settings.keep_alive
        return body

    def chat(self, request: ChatRequest) -> ChatResult:
        """One non-streaming chat call."""
        post = self.post_chat(request)
        reply, data = post.reply, post.reply.data
        message = data.get("message")
        content = message.get("content") if isinstance(message, dict) else None
        if not isinstance(content, str):
            raise ModelError(f"ollama: reply has no message.content (keys: {', '.join(sorted(data))[:80]})")
        done = text_or_none(data.get("done_reason"), "ollama: reply's done_reason")
        meta: dict[str, Any] = {**post.meta(), "done_reason": done}
        for key in ("total_duration", "load_duration", "prompt_eval_duration", "eval_duration"):
            nanoseconds = duration(data.get(key), f"ollama: reply's {key}")
            if nanoseconds is not None:
                meta[f"{key}_s"] = round(nanoseconds * NS, 4)
        return ChatResult(
            text=content,
            latency_s=reply.elapsed_s,
            model=text_or_none(data.get("model"), "ollama: reply's model") or str(self.arg),
            prompt_tokens=token_count(data.get("prompt_eval_count"), "ollama: reply's prompt_eval_count"),
            completion_tokens=token_count(data.get("eval_count"), "ollama: reply's eval_count"),
            meta=meta,
        )

    @classmethod
    def status(cls, arg: str | None = None) -> BackendStatus:
        """Server reachable (GET /api/tags, short timeout) and the model pulled."""
        host = ollama_host()
        model = arg or cls.default_arg or ""
        headers, secrets = bearer(_api_key())
        try:
            reply = probe(cls.name, host, "/api/tags", headers=headers, secrets=secrets, timeout_s=1.5)
        except ModelError as err:
            return BackendStatus(False, f"no server at {host} ({short_reason(err)})")
        names = [m.get("name", "") for m in reply.data.get("models", []) if isinstance(m, dict)]
        if model_listed(model, names):
            return BackendStatus(True, f"server at {host}, model {model} present")
        return BackendStatus(False, f"server at {host}, but model {model} is not pulled (ollama pull {model})")
