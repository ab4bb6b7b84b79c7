"""One loaded model for a whole sweep: a `LlamaServer` in a child process, with a slot per worker.

`SharedModel` (a context manager) starts `python -m llmnav.serve.shared` with the model, the number of
slots, the context per slot and the threads; the child loads the model, listens on 127.0.0.1 only (a
port the OS picks) with a random key, and writes its base URL on stdout once it is ready. `env()` gives
the variables that point the workers' `local` backends at it (`llmnav.backends.served`).

The child never outlives the sweep: it stops when its stdin, a pipe the parent holds, reaches its end
(the parent closed it, exited or was killed, SIGKILL included), on SIGTERM and on Ctrl-C. Leaving the
context terminates it and waits for it; it is killed if it does not end within `STOP_TIMEOUT_S`.
"""

from __future__ import annotations

import os
import secrets
import signal
import subprocess
import sys
import threading
from pathlib import Path
from types import FrameType, TracebackType

from llmnav.backends.served import ServedModel
from llmnav.errors import LlmnavError, ModelUnavailableError, one_line
from llmnav.serve import LOOPBACK, LlamaServer, ServeOptions

READY_TIMEOUT_S = 120.0  # [s] loading the model; the embedded 135M one takes about a second
STOP_TIMEOUT_S = 10.0  # [s] then the child is killed
_KEY_ENV = "LLMNAV_SHARED_MODEL_KEY"  # the key travels to the child in its environment, not its argv


class SharedModel:
    """A model server process for one sweep (`with SharedModel(path, slots=2) as served:`)."""

    def __init__(self, model_path: Path, *, slots: int, n_ctx: int, threads: int) -> None:
        self.model_path = Path(model_path)
        self.slots = slots
        self.n_ctx = n_ctx
        self.threads = threads
        self.process: subprocess.Popen[str] | None = None
        self.served: ServedModel | None = None

    def start(self) -> ServedModel:
        """Start the child and wait until its model is loaded; `ModelUnavailableError` when it cannot serve."""
        key = secrets.token_hex(16)
        # The child imports the llmnav this process runs, whatever the current folder holds (-P: no
        # current folder on its path; the folder holding this llmnav first on PYTHONPATH).
        command = [
            sys.executable, "-P", "-m", "llmnav.serve.shared",
            str(self.model_path), str(self.slots), str(self.n_ctx), str(self.threads),
        ]  # fmt: skip
        ours = str(Path(__file__).resolve().parents[2])
        path = os.pathsep.join(p for p in (ours, os.environ.get("PYTHONPATH", "")) if p)
        self.process = subprocess.Popen(
            command,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env={**os.environ, "PYTHONPATH": path, _KEY_ENV: key},
        )
        url = _first_line(self.process, READY_TIMEOUT_S)
        if not url.startswith("http://127.0.0.1:"):
            error = self._stop()
            raise ModelUnavailableError(f"the shared model server did not start: {error or 'no address given'}")
        self.served = ServedModel(url, self.n_ctx, self.model_path, key)
        return self.served

    def stop(self) -> None:
        """End the child (closing its stdin, then SIGTERM, then SIGKILL) and reap it."""
        self._stop()

    def _stop(self) -> str:
        """Stop the child; the last line it wrote on stderr (its error, when it failed)."""
        process, self.process = self.process, None
        if process is None:
            return ""
        if process.stdin is not None:
            try:
                process.stdin.close()  # the child's signal to stop
            except OSError:
                pass
        try:
            process.wait(STOP_TIMEOUT_S / 2)
        except subprocess.TimeoutExpired:
            process.terminate()
            try:
                process.wait(STOP_TIMEOUT_S / 2)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
        errors = process.stderr.read() if process.stderr is not None else ""
        for stream in (process.stdout, process.stderr):
            if stream is not None:
                stream.close()
        return (errors.strip().splitlines() or [""])[-1]

    def __enter__(self) -> ServedModel:
        return self.start()

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None, tb: TracebackType | None) -> None:
        self._stop()


def _first_line(process: subprocess.Popen[str], timeout_s: float) -> str:
    """The child's first stdout line, or "" if it ended or said nothing within `timeout_s`."""
    lines: list[str] = []

    def read() -> None:
        assert process.stdout is not None
        lines.append(process.stdout.readline())

    reader = threading.Thread(target=read, name="llmnav-shared-model-ready", daemon=True)
    reader.start()
    reader.join(timeout_s)
    return lines[0].strip() if lines else ""


def _stop_on_sigterm(signum: int, frame: FrameType | None) -> None:
    raise KeyboardInterrupt


def main(argv: list[str]) -> int:
    """The child: serve the model on loopback until stdin ends, SIGTERM or Ctrl-C."""
    path, slots, n_ctx, threads = Path(argv[0]), int(argv[1]), int(argv[2]), int(argv[3])
    options = ServeOptions(
        model=path, host=LOOPBACK, port=0, parallel=slots, n_ctx=n_ctx, threads=threads,
        api_key=os.environ.pop(_KEY_ENV, None),
    )  # fmt: skip
    server = LlamaServer(options)
    signal.signal(signal.SIGTERM, _stop_on_sigterm)
    try:
        info = server.start()
        print(info.url.removesuffix("/v1"), flush=True)
        sys.stdin.read()  # returns when the parent closes the pipe or dies
    except LlmnavError as err:
        print(one_line(err), file=sys.stderr, flush=True)
        return 1
    except KeyboardInterrupt:
        pass
    finally:
        server.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
