"""A backend run in a process of its own, for a control loop that must never wait on it.

An in-process engine (llama.cpp through xllamacpp) runs inside the Python process, and the thread that
calls it takes the GIL around each call; a 50 Hz loop thread in the same process then waits for the GIL,
however high its own scheduling priority, for as long as that thread holds it or is preempted holding it
(measured under SCHED_FIFO at load 3-7: a detector call of 8.4 ms CPU took 26.8 ms, a tick started
14.8 ms late). `ModelProcess` runs the backend in a child interpreter instead, so the loop's process
runs no Python thread but the loop:

- the child is a fresh interpreter (`python -m llmnav.backends.isolated FD`), not a fork of a process
  holding a simulator and threads, and it rebuilds the backend from its spec and options;
- it lowers its own priority by `nice` (`MODEL_NICE` by default) before loading the model, so on a busy
  machine the loop's process (and the simulation in it) can go first; no GIL is shared, so a niced model
  makes nobody wait (in the loop's own process, it would hold the GIL while preempted);
- the two talk over a private socket pair with `multiprocessing.connection` framing: `submit` and
  `poll` never block on the model, so the loop thread itself can call them between ticks;
- a failure in the child comes back as the same `LlmnavError` it raised (a `ModelError` when it cannot
  be sent), and a child that died or stopped answering is a `ModelError` at every later call, never a
  hang.
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import time
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

import llmnav
from llmnav.backends.base import Backend, ChatRequest, ChatResult, get_backend
from llmnav.backends.local import beside_simulation
from llmnav.errors import LlmnavError, ModelError, one_line

MODEL_NICE = 5  # the child's nice value above its parent's: the loop's process runs first on a busy core
START_TIMEOUT_S = 120.0  # [s] loading a model on a loaded 2-core machine takes a few seconds
CALL_TIMEOUT_S = 300.0  # [s] a blocking call (the schema probe) on a very busy machine
STOP_TIMEOUT_S = 2.0  # [s] after that the child is killed (it may be in the middle of a generation)

Reply = tuple[ChatResult | None, LlmnavError | None, float]  # (result, error, the call's wall time [s])


class ModelProcess:
    """A backend (`spec`, `options`, as for `get_backend`) served by a child process.

    `chat`/`check_schema` block; `submit` + `poll` do not (one request in flight at a time). Use as a
    context manager or call `close`.
    """

    def __init__(self, spec: str, options: dict[str, Any] | None = None, *, nice: int = MODEL_NICE) -> None:
        ours, theirs = socket.socketpair()
        self.spec = spec
        self._in_flight = False
        self._dead: str | None = None  # why the child cannot answer any more
        try:
            self._process = subprocess.Popen(
                [sys.executable, "-m", __name__, str(theirs.fileno()), str(nice)],
                pass_fds=(theirs.fileno(),),
                stdin=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL,  # never mixed into the CLI's own output (`--json`)
                env=_child_environment(),
            )
        finally:
            theirs.close()
        self._conn = Connection(ours.detach())
        try:
            self._send((spec, options or {}))  # answered like a call: once the model is loaded
            self._wait(START_TIMEOUT_S, "start")
        except BaseException:
            self.close()
            raise

    @property
    def pid(self) -> int:
        """The child's process id."""
        return self._process.pid

    # --- blocking calls ---------------------------------------------------------------------------
    def chat(self, request: ChatRequest) -> ChatResult:
        """Answer one request (blocks until the child has answered)."""
        self.submit(request)
        result = self._wait(CALL_TIMEOUT_S, "chat")
        assert isinstance(result, ChatResult)
        return result

    def check_schema(self, schema: dict[str, Any]) -> None:
        """The backend's `check_schema`, run in the child (where the model is)."""
        self._send(("check_schema", schema))
        self._wait(CALL_TIMEOUT_S, "check_schema")

    # --- non-blocking calls -----------------------------------------------------------------------
    def submit(self, request: ChatRequest) -> None:
        """Send a request without waiting (one at a time; a dead child answers it with an error)."""
        if self._in_flight:
            raise RuntimeError("ModelProcess: a request is already in flight")
        self._send(("chat", request))

    def poll(self) -> Reply | None:
        """The answer to the request in flight once it is there (never blocks on the model), else None."""
        if not self._in_flight:
            return None
        if self._dead is None:
            try:
                if not self._conn.poll(0):
                    return None
                ok, value, took = self._conn.recv()
            except (EOFError, OSError):
                self._dead = self._ended()
            else:
                self._in_flight = False
                if ok:
                    return value, None, took
                return None, value, took
        self._in_flight = False
        return None, ModelError(f"{self.spec}: {self._dead}"), 0.0

    @property
    def dead(self) -> str | None:
        """Why the child cannot answer any more (None while it can)."""
        return self._dead

    # --- life cycle -------------------------------------------------------------------------------
    def close(self) -> None:
        """Stop the child: end of input first, then a kill if it is still generating after STOP_TIMEOUT_S."""
        self._conn.close()
        try:
            self._process.wait(timeout=STOP_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            self._process.kill()
            self._process.wait()

    def __enter__(self) -> ModelProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # --- helpers ----------------------------------------------------------------------------------
    def _send(self, message: tuple[Any, Any]) -> None:
        self._in_flight = True
        if self._dead is not None:
            return
        try:
            self._conn.send(message)
        except OSError:  # a broken pipe: the child is gone
            self._dead = self._ended()

    def _wait(self, timeout_s: float, what: str) -> Any:
        """The value of the answer in flight, waiting up to `timeout_s`; its error is raised here."""
        deadline = time.monotonic() + timeout_s
        while True:
            if self._dead is None and not self._conn.poll(min(0.5, max(0.0, deadline - time.monotonic()))):
                if self._process.poll() is not None:
                    self._dead = self._ended()
                elif time.monotonic() >= deadline:  # its answer could come any time later: never use it
                    self._dead = f"the model process gave no answer to {what} in {timeout_s:.0f} s"
                continue
            reply = self.poll()
            if reply is not None:
                result, error, _ = reply
                if error is not None:
                    raise error
                return result

    def _ended(self) -> str:
        try:
            code = self._process.wait(timeout=STOP_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            return "the model process stopped answering"
        return f"the model process ended (exit code {code})"


def _child_environment() -> dict[str, str]:
    """The environment with the folder this `llmnav` was imported from first on the child's path.

    The child must run the same code as the parent (a checkout or a test's path, not another install).
    """
    root = str(Path(llmnav.__file__).resolve().parents[1])
    path = os.environ.get("PYTHONPATH", "")
    return {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in (root, path) if p)}


# --- the child ---------------------------------------------------------------------------------------


def _serve(conn: Connection, nice: int) -> None:
    """Build the backend, then answer requests until the parent closes its end."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle; it closes us
    try:
        os.nice(nice)
    except OSError:  # lowering one's own priority is always permitted; a sandbox may refuse anyway
        pass
    spec, options = conn.recv()
    backend: Backend | None = None
    try:
        backend = get_backend(spec, **options)
        loaded = getattr(backend, "load", None)
        if loaded is not None:  # pay the load now, before the parent's clock starts
            loaded()
        _answer(conn, True, getattr(backend, "spec", spec), 0.0)
    except LlmnavError as err:
        _answer(conn, False, err, 0.0)
        return
    while True:
        try:
            op, arg = conn.recv()
        except EOFError:
            break
        started = time.perf_counter()
        try:
            with beside_simulation():  # it runs beside the parent's live simulation
                value = backend.chat(arg) if op == "chat" else None
                if op == "check_schema":
                    backend.check_schema(arg)
        except LlmnavError as err:
            _answer(conn, False, err, time.perf_counter() - started)
        else:
            _answer(conn, True, value, time.perf_counter() - started)
    backend.close()


def _answer(conn: Connection, ok: bool, value: Any, took: float) -> None:
    try:
        conn.send((ok, value, took))
    except OSError:  # the parent has gone (it closed while we generated): nobody to answer
        return
    except Exception as err:  # noqa: BLE001 - an error object that cannot be pickled still gets an answer
        with contextlib.suppress(OSError):
            conn.send((False, ModelError(one_line(str(value) if not ok else err)), took))


if __name__ == "__main__":
    _serve(Connection(int(sys.argv[1])), int(sys.argv[2]))
