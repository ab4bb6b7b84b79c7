"""`llmnav serve`: serve a GGUF model over OpenAI's API with llama.cpp's server until Ctrl-C.

Data on stdout (the base URL, then the `--backend` value to use, one per line, flushed as soon as the
model is ready, so a script can read them); everything else on stderr.
"""

from __future__ import annotations

import os
import signal
import threading
from pathlib import Path
from types import FrameType
from typing import Annotated

import typer

from llmnav.commands.common import cli_errors, err_console
from llmnav.errors import BadInputError, validation_message


def _stop_on_sigterm(signum: int, frame: FrameType | None) -> None:
    raise KeyboardInterrupt  # `kill PID` stops the server as cleanly as Ctrl-C


_HANDLERS = {signal.SIGINT: signal.default_int_handler, signal.SIGTERM: _stop_on_sigterm}


def _take_back_signals() -> None:
    """Make Ctrl-C and SIGTERM Python's again where llama.cpp's own server thread installed its handlers.

    That thread may do so after `start` returned, and a SIGINT then goes to llama.cpp and the process never
    stops (three servers in one loaded full-suite run ignored it for 60 s; not reproduced alone), so the
    main thread checks while it waits.
    """
    for sig, handler in _HANDLERS.items():
        if signal.getsignal(sig) is not handler:
            signal.signal(sig, handler)


@cli_errors
def serve(
    model: Annotated[
        Path | None, typer.Option("--model", help="GGUF model file (default: the embedded SmolLM2-135M).")
    ] = None,
    host: Annotated[str, typer.Option("--host", help="Address to listen on (default loopback only).")] = "127.0.0.1",
    port: Annotated[int, typer.Option("--port", min=0, max=65535, help="TCP port; 0 picks a free one.")] = 8080,
    parallel: Annotated[
        int, typer.Option("--parallel", min=1, max=64, help="Slots: requests served at the same time.")
    ] = 1,
    n_ctx: Annotated[int, typer.Option("--ctx", min=256, help="Context tokens per slot.")] = 4096,
    threads: Annotated[
        int | None, typer.Option("--threads", min=1, help="CPU threads (default: the cores but one).")
    ] = None,
    api_key: Annotated[
        str | None,
        typer.Option("--api-key", help="Key clients must send as a Bearer token (default $LLMNAV_API_KEY)."),
    ] = None,
    aliases: Annotated[
        list[str] | None,
        typer.Option(
            "--alias",
            metavar="NAME",
            help="Another model name clients may use (repeatable); besides 'local', any other name gets 404.",
        ),
    ] = None,
    verbose: Annotated[bool, typer.Option("--verbose", help="Let llama.cpp log to stderr.")] = False,
) -> None:
    """Serve a model over HTTP (OpenAI-compatible) so runs and sweep workers can share one loaded copy."""
    # deferred: the server brings pydantic (about 0.1 s), not for `llmnav --help`
    from pydantic import ValidationError

    from llmnav.serve import CLIENT_KEY_VARIABLE, KEY_VARIABLE, LOOPBACK, LlamaServer, ServeOptions, check_host

    key = api_key or os.environ.get(KEY_VARIABLE, "").strip() or None
    host = check_host(host, key)  # before the model loads: an empty host, or one off loopback with no key
    for name in aliases or ():
        if not name.strip() or name != name.strip():
            raise BadInputError(f"--alias {name!r}: give a model name, without spaces around it")
    try:
        options = ServeOptions(
            model=model, host=host, port=port, parallel=parallel, n_ctx=n_ctx, threads=threads, api_key=key,
            aliases=tuple(aliases or ()), verbose=verbose,
        )  # fmt: skip
    except ValidationError as err:
        raise BadInputError(f"--{validation_message(err)}") from None
    server = LlamaServer(options)
    info = server.start(lambda path: err_console.print(f"loading {path} …", highlight=False, soft_wrap=True))
    try:
        main = threading.current_thread() is threading.main_thread()
        if main:
            _take_back_signals()
        typer.echo(info.url)
        typer.echo(f"--backend {info.backend_spec}")
        names = ", ".join((info.name, *info.aliases))
        err_console.print(
            f"serving {info.model_path.name} on {info.url} — {info.parallel} slot(s) of {info.n_ctx} tokens, "
            f"{info.threads} thread(s), as {names}; Ctrl-C stops it",
            highlight=False,
            soft_wrap=True,
        )
        if info.host != LOOPBACK:  # check_host let it through with a key only
            err_console.print(f"listening on {info.host}: other machines can reach it, with the key", highlight=False)
        if info.has_key:
            err_console.print(f"clients must send the key: set {CLIENT_KEY_VARIABLE} to it", highlight=False)
        idle = threading.Event()
        while not idle.wait(0.2):  # until Ctrl-C / SIGTERM
            if main:
                _take_back_signals()
    except KeyboardInterrupt:
        pass
    finally:
        server.stop()
    err_console.print("server stopped", highlight=False)
