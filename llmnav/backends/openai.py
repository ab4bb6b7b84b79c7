"""OpenAI-compatible backend: `openai[:MODEL][@BASE_URL]` → POST {BASE_URL}/chat/completions.

Works with OpenAI itself and with local OpenAI-compatible servers (llama.cpp server, vLLM, LM Studio).
Base URL: the `@` part of the spec, else the `base_url` option, else `OPENAI_BASE_URL`, else
https://api.openai.com/v1. `OPENAI_API_KEY` is sent as a Bearer token when set; it is required only for
api.openai.com. Images travel as `image_url` data URLs; the schema as `response_format: json_schema`.

Scoring (`score`): against llama.cpp's server (`llama-server`, `llmnav serve`) the backend scores
continuations exactly as the in-process engine does (`llmnav.backends.forced`), through the server's
`/tokenize` and `/completions`. Whether a server can is probed once (its `/tokenize` answers with token
ids); other OpenAI-compatible servers cannot, and a planner deciding `auto` generates instead.
"""

from __future__ import annotations

import os
from typing import Any, ClassVar, Literal

from pydantic import Field

from llmnav.backends.base import (
    BackendStatus,
    ChatRequest,
    ChatResult,
    Check,
    ScoreRequest,
    ScoreResult,
)
from llmnav.backends.forced import normalised, score_continuations
from llmnav.backends.http import (
    HttpBackend,
    HttpOptions,
    HttpStatusError,
    JsonHttpClient,
    bearer,
    normalise_url,
    probe,
    short_reason,
)
from llmnav.backends.reply import obj, seq, text_or_none, token_ids, usage_counts
from llmnav.errors import BackendSpecError, MissingKeyError, ModelError, one_line

DEFAULT_BASE_URL = "https://api.openai.com/v1"
DEFAULT_MODEL = "gpt-4o-mini"
KEY_VARIABLE = "OPENAI_API_KEY"
PROBE_TIMEOUT_S = 10.0  # [s] asking /tokenize whether the server scores (it answers in milliseconds)


class OpenAIOptions(HttpOptions):
    """OpenAI knobs on top of the shared HTTP options."""

    timeout_s: float = Field(default=90.0, gt=0)  # [s]
    strict: bool = False  # json_schema strict mode (OpenAI then demands additionalProperties: false)
    schema_name: str = "answer"  # json_schema.name
    json_mode: bool = True  # response_format json_object when a request carries no schema
    max_tokens_field: Literal["max_tokens", "max_completion_tokens"] = "max_tokens"  # newer models


def split_arg(arg: str | None) -> tuple[str, str | None]:
    """`MODEL@BASE_URL` → (model, base URL or None)."""
    model, at, base = (arg or "").partition("@")
    if at and not base.strip():  # never a silent switch to the public endpoint (with OPENAI_API_KEY)
        raise BackendSpecError(f"openai:{arg}: no server URL after '@' (give MODEL@URL, or leave out the '@')")
    return model or DEFAULT_MODEL, (base or None)


def resolve_base(spec_base: str | None, option_base: str | None = None) -> str:
    """Spec `@URL`, option, `OPENAI_BASE_URL`, default — first one set."""
    return normalise_url(spec_base or option_base or os.environ.get("OPENAI_BASE_URL") or DEFAULT_BASE_URL)


def _api_key() -> str | None:
    return os.environ.get(KEY_VARIABLE, "").strip() or None


def _is_official(base: str) -> bool:
    return "api.openai.com" in base


class OpenAIBackend(HttpBackend):
    """Any server speaking OpenAI's chat-completions API."""

    name = "openai"
    default_arg = DEFAULT_MODEL
    description = "OpenAI or a compatible server (OPENAI_API_KEY, OPENAI_BASE_URL)"
    example = "openai:gpt-4o-mini@http://127.0.0.1:8080/v1"
    multimodal = True
    options_model: ClassVar[type[HttpOptions]] = OpenAIOptions
    chat_path: ClassVar[str] = "/chat/completions"
    models_path: ClassVar[str] = "/models"

    def __init__(self, arg: str | None = None, **options: Any) -> None:
        super().__init__(arg, **options)
        self.model, spec_base = split_arg(self.arg)
        self.base_url = resolve_base(spec_base, self.settings.base_url)
        self.__key = _api_key()
        if self.__key is None and _is_official(self.base_url):
            raise MissingKeyError(f"openai needs an API key for {self.base_url}: set {KEY_VARIABLE}")
        self._scores: bool | None = None  # whether the server scores (probed on first use)
        self._root: JsonHttpClient | None = None
        self._tokens: dict[str, list[int]] = {}

    @classmethod
    def check_arg(cls, arg: str | None) -> None:
        """The spec's `@URL`, when given, must name a server (a host, a usable scheme and port)."""
        _, spec_base = split_arg(arg)
        if spec_base is not None:
            normalise_url(spec_base)

    def _root_client(self) -> JsonHttpClient:
        """A client for the server's root, where llama.cpp keeps `/tokenize` (the base URL ends in /v1)."""
        if self._root is None:
            root = self.base_url.removesuffix("/v1")
            headers, secrets = bearer(self.__key)
            self._root = JsonHttpClient(self.name, root, self.settings, headers=headers, secrets=secrets)
            self._root.cache = self.reply_cache
        return self._root

    def _tokenize(self, text: str) -> list[int]:
        found = self._tokens.get(text)
        if found is None:
            data = self._root_client().post("/tokenize", {"content": text, "add_special": True}).data
            found = self._tokens[text] = token_ids(data.get("tokens"), "openai: the server's /tokenize tokens")
        return found

    @property
    def can_score(self) -> bool:
        """Whether the server tokenises (llama.cpp's server does; OpenAI and most others do not).

        Asked once, in one short try (a dead server then costs one chat request's deadline, not two). A
        server that answers it has no `/tokenize` (404, 405, 501, or no token ids) does not score; one that
        fails (another 5xx, no connection) raises `ModelError`: a server failure ends the run as one,
        instead of turning a scoring run into a generating one.
        """
        if self._scores is None:
            if _is_official(self.base_url):
                self._scores = False
            else:
                body = {"content": "probe", "add_special": True}
                try:
                    reply = self._root_client().request(
                        "POST", "/tokenize", body, timeout_s=PROBE_TIMEOUT_S, retries=False
                    )
                except HttpStatusError as err:
                    if err.status >= 500 and err.status != 501:
                        raise
                    self._scores = False
                else:
                    tokens = reply.data.get("tokens")
                    self._scores = isinstance(tokens, list) and bool(tokens)
        return self._scores

    def score(self, request: ScoreRequest) -> ScoreResult:
        """Each continuation's log-probability, forced as its canonical tokens (see the module docstring)."""
        if not self.can_score:
            where = self.client.redact(self.base_url)
            raise ModelError(f"{self.spec.split('@')[0]} at {where} cannot score continuations")
        elapsed = 0.0
        states: set[str] = set()

        def complete(body: dict[str, Any]) -> dict[str, Any]:
            nonlocal elapsed
            reply = self.client.post("/completions", {"model": self.model, **body})
            elapsed += reply.elapsed_s
            states.add(reply.cache)
            return reply.data

        scores = tuple(score_continuations(request.prefix, request.continuations, self._tokenize, complete))
        # the call is a hit only when every continuation's reply came from the cache
        cache = "off" if not self.caching else ("hit" if states == {"hit"} else "miss")
        prefix_tokens = len(self._tokenize(normalised(request.prefix)))
        meta = {"mode": "score", "prefix_tokens": prefix_tokens, "cache": cache}
        return ScoreResult(scores, elapsed, self.model, meta)

    def check_server(self) -> list[Check]:
        """The shared probes, then whether the server scores continuations."""
        checks = super().check_server()
        if checks and checks[0].ok:
            # Not a failure when absent: planners then generate (`--decide auto`). A failing one is.
            try:
                ok = self.can_score
            except ModelError as err:
                checks.append(Check("scores continuations", False, f"/tokenize failed: {short_reason(err)}"))
                return checks
            detail = "tokenises: option texts can be scored" if ok else "no /tokenize: planners generate instead"
            checks.append(Check("scores continuations", True if ok else None, detail))
        return checks

    def close(self) -> None:
        """Close both connection pools."""
        super().close()
        if self._root is not None:
            self._root.close()
            self._root = None

    def _make_client(self) -> JsonHttpClient:
        headers, secrets = bearer(self.__key)
        return JsonHttpClient(self.name, self.base_url, self.settings, headers=headers, secrets=secrets)

    @property
    def model_name(self) -> str:
        """The model the spec names (without the `@URL`)."""
        return self.model

    def listed_models(self, data: dict[str, Any]) -> list[str]:
        """Ids (and llama.cpp's aliases) in a /models reply."""
        names: list[str] = []
        for entry in data.get("data") or []:
            if isinstance(entry, dict):
                for name in [entry.get("id"), *(entry.get("aliases") or [])]:
                    if isinstance(name, str) and name not in names:
                        names.append(name)
        return names

    def build_body(self, request: ChatRequest) -> dict[str, Any]:
        """The chat/completions body for a request."""
        settings = self.settings
        assert isinstance(settings, OpenAIOptions)
        messages: list[dict[str, Any]] = []
        for message in request.messages:
            if message.images:
                parts: list[dict[str, Any]] = [{"type": "text", "text": message.text}]
                parts += [
                    {"type": "image_url", "image_url": {"url": f"data:image/jpeg;base64,{img.jpeg_b64}"}}
                    for img in message.images
                ]
                messages.append({"role": message.role, "content": parts})
            else:
                messages.append({"role": message.role, "content": message.text})
        body: dict[str, Any] = {
            "model": self.model,
            "messages": messages,
            "temperature": request.temperature,
            settings.max_tokens_field: request.max_tokens,
        }
        if request.seed is not None:
            body["seed"] = request.seed
        if request.json_schema is not None:
            body["response_format"] = {
                "type": "json_schema",
                "json_schema": {
                    "name": settings.schema_name,
                    "schema": request.json_schema,
                    "strict": settings.strict,
                },
            }
        elif settings.json_mode:
            body["response_format"] = {"type": "json_object"}
        return body

    def chat(self, request: ChatRequest) -> ChatResult:
        """One chat-completions call."""
        post = self.post_chat(request)
        reply, data = post.reply, post.reply.data
        choices = seq(data.get("choices"), "openai: reply's choices")
        first = obj(choices[0], "openai: reply's choices[0]") if choices else {}
        message = first.get("message")
        if not isinstance(message, dict):
            raise ModelError("openai: reply has no choices[0].message")
        content = text_or_none(message.get("content"), "openai: reply's choices[0].message.content")
        if content is None:
            refusal = text_or_none(message.get("refusal"), "openai: reply's choices[0].message.refusal")
            why = f"model refused: {one_line(refusal, 200)}" if refusal else "reply has no content"
            raise ModelError(f"openai: {why}")
        prompt_tokens, completion_tokens = usage_counts(
            data.get("usage"), "openai: reply's usage", "prompt_tokens", "completion_tokens"
        )
        finish = text_or_none(first.get("finish_reason"), "openai: reply's choices[0].finish_reason")
        return ChatResult(
            text=content,
            latency_s=reply.elapsed_s,
            model=text_or_none(data.get("model"), "openai: reply's model") or self.model,
            prompt_tokens=prompt_tokens,
            completion_tokens=completion_tokens,
            meta={**post.meta(), "finish_reason": finish},
        )

    @classmethod
    def status(cls, arg: str | None = None) -> BackendStatus:
        """Server reachable: GET {base}/models with a short timeout."""
        _, spec_base = split_arg(arg)
        base = resolve_base(spec_base)
        key = _api_key()
        if key is None and _is_official(base):
            return BackendStatus(False, f"{KEY_VARIABLE} not set (needed for {base})")
        headers, secrets = bearer(key)
        try:
            probe(cls.name, base, "/models", headers=headers, secrets=secrets, timeout_s=3.0)
        except ModelError as err:
            return BackendStatus(False, f"{base} not usable: {short_reason(err)}")
        return BackendStatus(True, f"server reachable at {base}")
