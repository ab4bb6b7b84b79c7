"""llama.cpp held in process (`xllamacpp.Server`): the engine under the `local` backend and its shared server.

Grammar-constrained answers, prompt caching and forced-token scoring live here; which model file, how many
threads and who shares the engine are `llmnav.backends.local`'s concern (its docstring explains the modes).
"""

from __future__ import annotations

import json
import secrets
import time
from pathlib import Path
from typing import Any

from llmnav.backends.base import ChatRequest, ChatResult, Message, ScoreRequest, ScoreResult
from llmnav.backends.forced import normalised, score_continuations
from llmnav.backends.reply import duration, obj, seq, text_or_none, token_count, token_ids, usage_counts
from llmnav.errors import ModelError, ModelUnavailableError, one_line

# Compact JSON from llguidance: no optional whitespace, no blanks after separators.
_COMPACT_JSON = {"whitespace_flexible": False, "item_separator": ",", "key_separator": ":"}
TEXT_CAP_CHARS = 240  # free-text fields of a constrained answer: about 50 tokens, a few sentences
_JSON_VALUE_STARTS = frozenset('{["-0123456789tfn')  # how any compact JSON value begins
PROMPT_CACHE_RAM = 256  # [MiB] host-RAM copies of evicted prompt prefixes (llama.cpp default: 8 GiB)


def _import_xllamacpp() -> Any:
    try:
        # deferred: the xllamacpp engine (about 0.03 s) may be missing; only a local model needs it
        import xllamacpp
    except ImportError:
        raise ModelUnavailableError(
            "the local backend needs the xllamacpp engine: run `make install` or `pip install xllamacpp`"
        ) from None
    return xllamacpp


def _to_openai_messages(messages: tuple[Message, ...]) -> tuple[list[dict[str, str]], int]:
    """OpenAI-style text messages and the number of images dropped (the model reads text only)."""
    out = [{"role": m.role, "content": m.text} for m in messages]
    return out, sum(len(m.images) for m in messages)


class LlamaCppEngine:
    """A GGUF model held by an in-process `xllamacpp.Server`."""

    def __init__(self, path: Path, *, n_ctx: int, threads: int, verbose: bool) -> None:
        xllamacpp = _import_xllamacpp()
        params = xllamacpp.CommonParams()
        params.model.path = str(path)
        params.n_ctx = n_ctx
        params.n_parallel = 1  # one slot: one conversation prefix stays hot in the KV cache
        params.cache_prompt = True
        params.cache_ram_mib = PROMPT_CACHE_RAM
        params.cpuparams.n_threads = threads
        params.cpuparams_batch.n_threads = threads
        # 0 silences llama.cpp entirely (its default, 3, writes every load step and timing to stderr).
        params.verbosity = 3 if verbose else 0
        # The server also listens on a random loopback port; a random key keeps other local users out.
        self._key = secrets.token_hex(16)
        params.api_keys = [self._key]
        try:
            self._server = xllamacpp.Server(params)
        except RuntimeError:
            raise ModelUnavailableError(f"llama.cpp could not load {path} (not a GGUF model?)") from None
        self._tokens: dict[str, list[int]] = {}  # text -> token ids (tokenising is an HTTP round trip)
        self._tokenizer_client: Any = None  # httpx.Client to the server's /tokenize, made at first use
        self.model_name = path.name.removesuffix(".gguf")
        self.n_ctx = n_ctx
        self.threads = threads
        self._checked_schemas: set[str] = set()

    def generate(self, request: ChatRequest) -> ChatResult:
        """Run one chat completion, grammar-constrained when the request carries a JSON Schema."""
        messages, dropped = _to_openai_messages(request.messages)
        body: dict[str, Any] = {
            "messages": messages,
            "temperature": request.temperature,
            "max_tokens": request.max_tokens,
            "cache_prompt": True,
        }
        if request.seed is not None:
            body["seed"] = request.seed
        if request.json_schema is not None:
            self.check_schema(request.json_schema)  # once per schema: llguidance fails silently
            body["grammar"] = compact_grammar(request.json_schema)
        started = time.perf_counter()
        try:
            reply = self._chat_completions(body)
        except ValueError as err:  # e.g. a schema llama.cpp cannot turn into a grammar
            raise ModelError(f"local model rejected the request: {one_line(str(err))}") from None
        latency = time.perf_counter() - started
        if "error" in reply:
            error = reply["error"]
            message = error.get("message", error) if isinstance(error, dict) else error
            raise ModelError(f"local model failed: {one_line(str(message))}")
        choices = seq(reply.get("choices"), "local model: reply's choices")
        choice = obj(choices[0], "local model: reply's choices[0]") if choices else {}
        message = obj(choice.get("message"), "local model: reply's choices[0].message")
        if not message:
            raise ModelError("local model returned a reply without choices")
        text = text_or_none(message.get("content"), "local model: reply's choices[0].message.content") or ""
        prompt_tokens, completion_tokens = usage_counts(
            reply.get("usage"), "local model: reply's usage", "prompt_tokens", "completion_tokens"
        )
        timings = obj(reply.get("timings"), "local model: reply's timings")
        meta: dict[str, Any] = {
            "engine": "xllamacpp",
            "finish_reason": text_or_none(choice.get("finish_reason"), "local model: reply's finish_reason"),
            "cached_tokens": token_count(timings.get("cache_n"), "local model: reply's timings.cache_n"),
            "new_prompt_tokens": token_count(timings.get("prompt_n"), "local model: reply's timings.prompt_n"),
            "prompt_ms": _rounded(timings.get("prompt_ms"), "prompt_ms"),
            "generation_ms": _rounded(timings.get("predicted_ms"), "predicted_ms"),
            "tokens_per_s": _rounded(timings.get("predicted_per_second"), "predicted_per_second"),
            "constrained": request.json_schema is not None,
        }
        if dropped:
            meta["images_dropped"] = dropped
        return ChatResult(
            text=text,
            latency_s=latency,
            model=self.model_name,
            prompt_tokens=prompt_tokens,
            completion_tokens=completion_tokens,
            meta=meta,
        )

    # How requests reach llama.cpp: its server's handlers in this process (`ServedEngine` sends the same
    # requests over HTTP to a server another process holds).
    def _chat_completions(self, body: dict[str, Any]) -> dict[str, Any]:
        return dict(self._server.handle_chat_completions(body))

    def _completions(self, body: dict[str, Any]) -> dict[str, Any]:
        return dict(self._server.handle_completions(body))

    def _tokenizer(self) -> Any:
        """A kept-alive client for the server's `/tokenize`, with its key.

        One connection for every call: a fresh connection per call cost about 23 ms a text on one core,
        a kept-alive one about 1 ms, and a scored decision tokenises dozens of new texts.
        """
        if self._tokenizer_client is None:
            # deferred: httpx (about 0.1 s) loads only when a prompt is tokenized
            import httpx

            self._tokenizer_client = httpx.Client(
                base_url=self._server.listening_address,
                headers={"Authorization": f"Bearer {self._key}"},
                timeout=30.0,
                trust_env=False,  # loopback: never through a proxy
            )
        return self._tokenizer_client

    def tokenize(self, text: str) -> list[int]:
        """The model's token ids for `text` as a prompt (with the model's start token, if it uses one).

        The engine has no in-process tokeniser call, so this asks the server's own `/tokenize` on its
        loopback address.
        """
        found = self._tokens.get(text)
        if found is None:
            # deferred: httpx (about 0.1 s) loads only when a prompt is tokenized
            import httpx

            try:
                reply = self._tokenizer().post("/tokenize", json={"content": text, "add_special": True})
                reply.raise_for_status()
                tokens = reply.json()["tokens"]
            except (httpx.HTTPError, ValueError, KeyError, TypeError) as err:
                raise ModelError(f"local model could not tokenise a scoring prompt: {one_line(err)}") from None
            found = self._tokens[text] = token_ids(tokens, "local model's tokeniser reply")
        return found

    def score(self, request: ScoreRequest) -> ScoreResult:
        """Each continuation's log-probability after the prefix, from llama.cpp's own token log-probabilities.

        The continuation is forced as its canonical tokens (those of prefix + continuation after the
        prefix's own, see `continuation_tokens`) by an llguidance grammar; llama.cpp reports each forced
        token's log-probability from the logits before grammar and sampler, so the sum is exact. The
        prefix stays in the prompt cache, and a position several continuations share is evaluated once
        for all of them (`llmnav.backends.forced.score_continuations`).
        """
        started = time.perf_counter()
        scores = tuple(score_continuations(request.prefix, request.continuations, self.tokenize, self._forced))
        latency = time.perf_counter() - started
        meta = {"engine": "xllamacpp", "mode": "score", "prefix_tokens": len(self.tokenize(normalised(request.prefix)))}
        return ScoreResult(scores, latency, self.model_name, meta)

    def _forced(self, body: dict[str, Any]) -> dict[str, Any]:
        try:
            return self._completions(body)
        except ValueError as err:
            raise ModelError(f"local model rejected a scoring request: {one_line(str(err))}") from None

    def check_schema(self, schema: dict[str, Any]) -> None:
        """Raise `ModelError` unless llama.cpp constrains answers to `schema` (see the module docstring).

        A probe asks for the word Hello in two tokens. Under a working grammar the answer must begin like
        a JSON value (`{`, `[`, `"`, a digit, `-`, `t`, `f`, `n`); a grammar that failed to compile leaves
        the model free, and it writes "Hello". Each schema is probed once per loaded model.
        """
        key = json.dumps(schema)
        if key in self._checked_schemas:
            return
        body: dict[str, Any] = {
            "messages": [{"role": "user", "content": "Write the word Hello."}],
            "temperature": 0.0,
            "max_tokens": 2,
            "cache_prompt": False,
            "grammar": compact_grammar(schema),
        }
        try:
            reply = self._chat_completions(body)
        except ValueError as err:
            raise ModelError(f"llama.cpp cannot compile the answer schema: {one_line(str(err))}") from None
        choices = reply.get("choices") or [{}]
        text = str((choices[0].get("message") or {}).get("content") or "")
        if "error" in reply or not text or text[0] not in _JSON_VALUE_STARTS:
            raise ModelError(
                f"llama.cpp cannot compile the answer schema into a grammar (unconstrained probe answer {text!r})"
            )
        self._checked_schemas.add(key)


def compact_grammar(schema: dict[str, Any]) -> str:
    """llama.cpp's grammar for `schema`, without optional whitespace (cached: the FSM sends one per tick).

    Key order is kept (it is the order the model writes the fields in: reasoning before the action).
    """
    return _compact_grammar(json.dumps(schema))


def _cap_free_text(schema: Any) -> None:
    """Give every free-text string without a length limit `TEXT_CAP_CHARS` (in place).

    A 135M model under a grammar can loop inside a string until `max_tokens` (seen: a stepwise
    `scene_description` repeating one sentence for 512 tokens, 72 s of decoding on a busy box); the
    schemas leave long caps out because other engines' grammars grow with them, llguidance's do not.
    """
    if isinstance(schema, dict):
        free = schema.get("type") == "string" and not {"maxLength", "enum", "const", "pattern"} & set(schema)
        if free:
            schema["maxLength"] = TEXT_CAP_CHARS
        for value in schema.values():
            _cap_free_text(value)
    elif isinstance(schema, list):
        for item in schema:
            _cap_free_text(item)


_GRAMMARS: dict[str, str] = {}


def _compact_grammar(schema_json: str) -> str:
    found = _GRAMMARS.get(schema_json)
    if found is None:
        xllamacpp = _import_xllamacpp()
        schema = json.loads(schema_json)
        _cap_free_text(schema)
        schema["x-guidance"] = {**_COMPACT_JSON, **schema.get("x-guidance", {})}
        found = _GRAMMARS[schema_json] = str(xllamacpp.json_schema_to_grammar(json.dumps(schema)))
    return found


def _rounded(value: Any, key: str) -> float | None:
    """A timing of llama.cpp's reply to 0.1 (absent: None; negative or not finite: ModelError)."""
    number = duration(value, f"local model: reply's timings.{key}")
    return None if number is None else round(number, 1)
