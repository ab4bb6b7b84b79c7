"""A GGUF model served over HTTP by llama.cpp's own server (through `xllamacpp.Server`), in this process.

The server speaks OpenAI's chat-completions API (`/v1/chat/completions`, `/v1/models`), so any run can
use it with `--backend openai:<alias>@<url>`. `--parallel N` gives it N slots: N episodes (the workers of
a sweep) share one loaded model instead of loading one copy each. Each slot gets `n_ctx` tokens of
context. It listens on 127.0.0.1 unless told otherwise; a key, when given, is required as a Bearer token.

llama.cpp's server installs its own SIGINT/SIGTERM handlers when it starts, which would make Ctrl-C do
nothing in the Python process; `LlamaServer.start` puts Python's handlers back.

Clients talk to llmnav's front (`llmnav.serve.front`), which relays to llama.cpp on a private loopback
port: it lets `stop` cut in-flight responses at once (llama.cpp alone would finish them first), answers
`GET /v1/models/{id}`, refuses model names other than the served one and its aliases, and gives OpenAI's
formats where llama.cpp's differ (docs/serve-api.md).
"""

from __future__ import annotations

import errno
import ipaddress
import signal
import socket
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field

from llmnav.backends.llamacpp import PROMPT_CACHE_RAM, _import_xllamacpp
from llmnav.backends.local import DEFAULT_N_CTX, default_model_path, default_threads
from llmnav.backends.local import _gguf_path as gguf_path  # the one check of a model path (exists, GGUF)
from llmnav.errors import BadInputError
from llmnav.serve.front import Front

LOOPBACK = "127.0.0.1"
DEFAULT_PORT = 8080
DEFAULT_ALIAS = "local"  # the model name clients use: `--backend openai:local@URL`
KEY_VARIABLE = "LLMNAV_API_KEY"  # the server's key when --api-key is not given
CLIENT_KEY_VARIABLE = "OPENAI_API_KEY"  # what the `openai` backend sends as its Bearer token


class ServeOptions(BaseModel):
    """How to serve: which model, where, how many slots, which key."""

    model_config = ConfigDict(extra="forbid")

    model: Path | None = None  # GGUF file; None = the embedded SmolLM2-135M
    host: str = LOOPBACK
    port: int = Field(default=DEFAULT_PORT, ge=0, le=65535)  # 0 = any free port
    parallel: int = Field(default=1, ge=1, le=64)  # slots: requests served at the same time
    n_ctx: int = Field(default=DEFAULT_N_CTX, ge=256)  # [tokens] context per slot
    threads: int | None = Field(default=None, ge=1)  # None = the usable cores but one
    api_key: str | None = None
    name: str = Field(default=DEFAULT_ALIAS, min_length=1)  # the model's name in /v1/models and replies
    aliases: tuple[Annotated[str, Field(min_length=1)], ...] = ()  # more names requests may give; others: 404
    verbose: bool = False  # let llama.cpp log every request and timing to stderr


@dataclass(frozen=True)
class ServerInfo:
    """What a client needs to know about a running server (never the key itself)."""

    model_path: Path
    host: str
    port: int
    name: str
    aliases: tuple[str, ...]
    parallel: int
    n_ctx: int
    threads: int
    has_key: bool

    @property
    def url(self) -> str:
        """The OpenAI-compatible base URL, e.g. http://127.0.0.1:8080/v1."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self.port}/v1"

    @property
    def backend_spec(self) -> str:
        """The `--backend` value that reaches this server."""
        return f"openai:{self.name}@{self.url}"


def served_names(options: ServeOptions) -> tuple[str, ...]:
    """The names requests may give: the served name first, then each alias once."""
    return tuple(dict.fromkeys((options.name, *options.aliases)))


def free_port(host: str = LOOPBACK) -> int:
    """A port the OS says is free on `host` now (another process may still take it before we do)."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as sock:
        sock.bind((host, 0))
        return int(sock.getsockname()[1])


def check_host(host: str, api_key: str | None) -> str:
    """The address to listen on for `--host`; BadInputError for an empty one, or one off loopback with no key.

    `localhost` is loopback (127.0.0.1). Any other address can be reached from other machines, so the
    server must want a key there: no one else's requests should run on this model.
    """
    text = host.strip()
    if not text:
        raise BadInputError("--host '': give an address: 127.0.0.1 (this machine only) or 0.0.0.0 (every interface)")
    if text.lower() == "localhost":
        return LOOPBACK
    try:
        loopback = ipaddress.ip_address(text.strip("[]")).is_loopback
    except ValueError:
        loopback = False  # a host name: whatever it resolves to, treat it as reachable from elsewhere
    if not loopback and not api_key:
        raise BadInputError(
            f"--host {text}: reachable from other machines; give a key with --api-key (or ${KEY_VARIABLE}), "
            "which clients send as $" + CLIENT_KEY_VARIABLE
        )
    return text.strip("[]")


def check_port(host: str, port: int) -> None:
    """Raise a one-line BadInputError when `host:port` cannot be bound (in use, or not an address here).

    llama.cpp's server reports every start failure as the same bare RuntimeError, so the common causes are
    checked first, the way the server itself binds (SO_REUSEADDR: a port in TIME_WAIT is free).
    """
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            sock.bind((host, port))
        except OSError as err:
            if err.errno == errno.EADDRINUSE:
                raise BadInputError(f"port {port} on {host} is already in use: choose another with --port") from None
            reason = err.strerror or str(err)
            raise BadInputError(f"cannot listen on {host}:{port}: {reason}") from None


class LlamaServer:
    """llama.cpp's HTTP server holding one model; a context manager (`with LlamaServer(opts) as info:`)."""

    def __init__(self, options: ServeOptions) -> None:
        self.options = options
        self._server: Any = None
        self._front: Any = None
        self.info: ServerInfo | None = None

    def start(self, on_loading: Callable[[Path], None] | None = None) -> ServerInfo:
        """Load the model and listen; returns once the model is ready. Bad input → one-line error.

        `on_loading(model_path)` is called once the cheap checks passed, before the slow model load.
        """
        opts = self.options
        path = gguf_path(str(opts.model)) if opts.model is not None else default_model_path()
        port = opts.port or free_port(opts.host)
        check_port(opts.host, port)
        xllamacpp = _import_xllamacpp()
        if on_loading is not None:
            on_loading(path)
        threads = opts.threads or default_threads()
        params = xllamacpp.CommonParams()
        params.model.path = str(path)
        params.model_alias = {opts.name}  # one name: llama.cpp lists the first of a set as the id
        params.hostnames = [LOOPBACK]  # only the front talks to llama.cpp
        params.port = free_port(LOOPBACK)
        params.n_parallel = opts.parallel
        params.n_ctx = opts.n_ctx * opts.parallel  # llama.cpp splits the context evenly among the slots
        params.cache_prompt = True
        params.cache_ram_mib = PROMPT_CACHE_RAM
        params.cpuparams.n_threads = threads
        params.cpuparams_batch.n_threads = threads
        params.verbosity = 3 if opts.verbose else 0
        if opts.api_key:
            params.api_keys = [opts.api_key]
        handlers = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
        try:
            self._server = xllamacpp.Server(params)
        except RuntimeError:
            raise BadInputError(
                f"llama.cpp's server did not start on {opts.host}:{port} with {path.name} "
                "(port taken meanwhile, or a model it cannot load)"
            ) from None
        finally:
            _restore_handlers(handlers)

        try:
            self._front = Front(opts.host, port, params.port, api_key=opts.api_key, names=served_names(opts))
        except OSError as err:
            self._server = None
            raise BadInputError(f"cannot listen on {opts.host}:{port}: {err.strerror or err}") from None
        self._front.start()
        self.info = ServerInfo(
            path,
            opts.host,
            port,
            opts.name,
            served_names(opts)[1:],
            opts.parallel,
            opts.n_ctx,
            threads,
            bool(opts.api_key),
        )
        return self.info

    def stop(self) -> None:
        """Stop listening, cut in-flight requests, free the model (llama.cpp's server ends with its object)."""
        if self._front is not None:
            self._front.stop()
            self._front = None
        self._server = None

    def __enter__(self) -> ServerInfo:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


def _restore_handlers(handlers: dict[signal.Signals, Any]) -> None:
    """Put back the Python-level signal handlers llama.cpp replaced (only possible in the main thread)."""
    for sig, handler in handlers.items():
        if handler is None:  # installed outside Python: leave it
            continue
        try:
            signal.signal(sig, handler)
        except ValueError:  # not the main thread
            return
