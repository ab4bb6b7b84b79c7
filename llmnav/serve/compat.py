"""What the front of `llmnav serve` changes so that OpenAI's SDKs get OpenAI's answers from llama.cpp.

llama.cpp's server speaks most of OpenAI's API; where it differs, code written for the SDK breaks. The
front (`llmnav.serve.front`) passes each request through `adapt_request` and each reply through the
adapter it returns:

- **Model names.** llama.cpp answers any `model` with its one model; OpenAI answers an unknown name with
  404 `model_not_found`. A request naming neither the served name nor one of its `--alias` names is
  refused before it reaches llama.cpp. A request with no `model` is still served (llama.cpp's own clients,
  and llmnav's, leave it out).
- **Legacy completion log-probabilities.** `/v1/completions` with `logprobs: N` gets llama.cpp's
  chat-style `logprobs.content`; OpenAI's legacy format is four parallel lists (`tokens`,
  `token_logprobs`, `top_logprobs`, `text_offset`). Both are given: the lists are added beside `content`,
  which llama.cpp-aware clients (llmnav's continuation scoring among them) read.
- **Structured output in the Responses API.** `/v1/responses` ignores `text.format`; it is handed to
  llama.cpp as the chat API's `response_format`, which it turns into a grammar.
- **True error texts.** llama.cpp's refusals tell the user to start it with flags (`--embeddings`) that
  `llmnav serve` does not have; those sentences are replaced by what is true of this server.

Everything here is pure: dictionaries in, dictionaries out; the front does the I/O.
"""

from __future__ import annotations

import json
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

# OpenAI's endpoints that take a `model` (llama.cpp also answers them without the /v1 prefix).
_MODEL_PATHS = frozenset({"chat/completions", "completions", "responses", "embeddings"})
_COMPLETIONS = "completions"
_RESPONSES = "responses"

# llama.cpp's hints that name a flag of its own command line, and what is true of `llmnav serve` instead.
_START_WITH = re.compile(r"\s*[Ss]tart it with `(?P<flag>--[a-z-]+)`\.?")
_INSTEAD = {
    "--embeddings": "llmnav serve loads its model for text generation only, so /v1/embeddings is not offered",
    "--reranking": "llmnav serve loads its model for text generation only, so reranking is not offered",
    "--props": "llmnav serve does not let clients change its settings",
    "--slots": "llmnav serve does not expose its slots",
    "--slot-save-path": "llmnav serve does not save or restore slots",
}
_NO_OPTION = "llmnav serve has no option to turn it on"


@dataclass(frozen=True)
class Refusal:
    """An answer the front gives itself, without asking llama.cpp."""

    status: int
    body: dict[str, Any]


def error_body(message: str, kind: str, code: str | int | None, param: str | None = None) -> dict[str, Any]:
    """OpenAI's error object."""
    return {"error": {"message": message, "type": kind, "param": param, "code": code}}


def endpoint(path: str) -> str:
    """The OpenAI endpoint a request path names ("/v1/chat/completions?x" → "chat/completions")."""
    bare = path.split("?", 1)[0].split("#", 1)[0].strip("/")
    return bare.removeprefix("v1/")


def unknown_model(model: str, names: Sequence[str]) -> Refusal:
    """OpenAI's 404 for a model this server does not serve, naming the ones it does."""
    message = f"The model `{model}` does not exist: this server serves {', '.join(f'`{n}`' for n in names)}"
    return Refusal(404, error_body(message, "invalid_request_error", "model_not_found", "model"))


def _bad_request(message: str, param: str) -> Refusal:
    return Refusal(400, error_body(message, "invalid_request_error", None, param))


@dataclass
class Adapted:
    """A request as llama.cpp should get it, and how to turn its reply into OpenAI's."""

    body: bytes
    legacy: LegacyLogprobs | None = None  # set for `/v1/completions` with `logprobs: N`

    def reply(self, data: dict[str, Any]) -> dict[str, Any]:
        """A successful reply, or one streamed event's data, as OpenAI would give it."""
        return self.legacy.reply(data) if self.legacy is not None else data

    @property
    def changes_replies(self) -> bool:
        """Whether llama.cpp's successful replies need changing (else they are relayed byte for byte)."""
        return self.legacy is not None


def adapt_request(method: str, path: str, body: bytes, names: Sequence[str]) -> Adapted | Refusal:
    """Check and rewrite one request for llama.cpp (see the module docstring); `names` empty: any model."""
    if method != "POST" or not body:
        return Adapted(body)
    route = endpoint(path)
    if route not in _MODEL_PATHS:
        return Adapted(body)
    try:
        request = json.loads(body)
    except (ValueError, RecursionError):
        return Adapted(body)  # llama.cpp says what is wrong with it
    if not isinstance(request, dict):
        return Adapted(body)
    model = request.get("model")
    if names and isinstance(model, str) and model not in names:
        return unknown_model(model, names)
    if route == _RESPONSES:
        refused = _responses_format(request)
        if isinstance(refused, Refusal):
            return refused
        return Adapted(json.dumps(request).encode()) if refused else Adapted(body)
    if route == _COMPLETIONS:
        wanted = request.get("logprobs")
        if isinstance(wanted, int) and not isinstance(wanted, bool) and wanted >= 0:
            # llama.cpp reports no log-probabilities for 0; OpenAI still gives the chosen token's
            request["logprobs"] = max(wanted, 1)
            legacy = LegacyLogprobs(_prompt_lengths(request.get("prompt")), wanted)
            return Adapted(json.dumps(request).encode(), legacy)
    return Adapted(body)


def _responses_format(request: dict[str, Any]) -> Refusal | bool:
    """Turn the Responses API's `text.format` into llama.cpp's `response_format`; True when it changed."""
    text = request.get("text")
    if not isinstance(text, dict) or text.get("format") is None:
        return False
    spec = text["format"]
    kind = spec.get("type") if isinstance(spec, dict) else None
    if kind == "text":
        return False
    if kind == "json_object":
        request["response_format"] = {"type": "json_object"}
        return True
    if kind != "json_schema":
        return _bad_request(
            f"text.format.type {kind!r}: expected 'text', 'json_object' or 'json_schema'", "text.format.type"
        )
    schema = spec.get("schema")
    if not isinstance(schema, dict):
        return _bad_request("text.format.schema: a JSON Schema object is required", "text.format.schema")
    named = {"name": spec["name"]} if isinstance(spec.get("name"), str) else {}
    request["response_format"] = {
        "type": "json_schema",
        "json_schema": {**named, "schema": schema, "strict": bool(spec.get("strict", False))},
    }
    return True


def _prompt_lengths(prompt: Any) -> list[int]:
    """Each prompt's length in characters, where a completion's `text_offset` starts (0 for token ids)."""
    if isinstance(prompt, str):
        return [len(prompt)]
    if isinstance(prompt, list) and prompt and all(isinstance(p, str) for p in prompt):
        return [len(p) for p in prompt]
    return []  # token ids (or nothing): offsets count from the completion's start


@dataclass
class LegacyLogprobs:
    """Adds OpenAI's legacy log-probability lists to llama.cpp's `choices[].logprobs`.

    `text_offset` counts characters from the start of the prompt (OpenAI's convention), so the first
    token's offset is the prompt's length; a streamed choice carries its offset from event to event.
    """

    prompt_lengths: list[int]
    top_n: int  # [alternatives] the `logprobs` the client asked for
    _offsets: dict[int, int] = field(default_factory=dict)

    def reply(self, data: dict[str, Any]) -> dict[str, Any]:
        """A completion reply (or a streamed chunk of one) with the lists beside each choice's `content`."""
        choices = data.get("choices")
        if not isinstance(choices, list):
            return data
        for choice in choices:
            if isinstance(choice, dict) and isinstance(choice.get("logprobs"), dict):
                index = choice.get("index")
                choice["logprobs"] = self._legacy(index if isinstance(index, int) else 0, choice["logprobs"])
        return data

    def _legacy(self, index: int, logprobs: dict[str, Any]) -> dict[str, Any]:
        content = logprobs.get("content")
        if not isinstance(content, list):
            return logprobs
        lengths = self.prompt_lengths
        offset = self._offsets.get(index, lengths[index] if index < len(lengths) else 0)
        tokens: list[str] = []
        token_logprobs: list[float | None] = []
        top_logprobs: list[dict[str, float]] = []
        text_offset: list[int] = []
        for item in content:
            if not isinstance(item, dict):
                continue
            token = str(item.get("token", ""))
            chosen = item.get("logprob")
            tokens.append(token)
            token_logprobs.append(float(chosen) if isinstance(chosen, int | float) else None)
            text_offset.append(offset)
            offset += len(token)
            # OpenAI: up to N alternatives, and the chosen token always among them (so up to N + 1)
            top: dict[str, float] = {}
            alternatives = item.get("top_logprobs")
            for alternative in alternatives[: self.top_n] if isinstance(alternatives, list) else []:
                if isinstance(alternative, dict) and isinstance(alternative.get("logprob"), int | float):
                    top.setdefault(str(alternative.get("token", "")), float(alternative["logprob"]))
            if isinstance(chosen, int | float):
                top.setdefault(token, float(chosen))
            top_logprobs.append(top)
        self._offsets[index] = offset
        return {
            "tokens": tokens,
            "token_logprobs": token_logprobs,
            "top_logprobs": top_logprobs,
            "text_offset": text_offset,
            **logprobs,
        }


def true_error(data: dict[str, Any]) -> dict[str, Any]:
    """llama.cpp's error reply with its advice to start it with a flag replaced by what is true here."""
    error = data.get("error")
    message = error.get("message") if isinstance(error, dict) else None
    if not isinstance(message, str):
        return data
    hint = _START_WITH.search(message)
    if hint is None:
        return data
    stated = message[: hint.start()].rstrip().rstrip(".")
    instead = _INSTEAD.get(hint["flag"], _NO_OPTION)
    assert isinstance(error, dict)
    error["message"] = f"{stated}: {instead}" if stated else instead
    return data
