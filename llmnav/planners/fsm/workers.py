"""Where the FSM's model runs under `--realtime`: a worker thread, or a process of its own for an in-process engine.

Either way the loop only submits a request and polls for the answer between ticks; it never waits.
"""

from __future__ import annotations

import contextlib
import queue
import threading
import time
from collections.abc import Callable
from typing import Any

from llmnav.backends.isolated import MODEL_NICE, ModelProcess
from llmnav.core.chat import ChatRequest, ChatResult
from llmnav.core.realtime import available_priority
from llmnav.errors import LlmnavError, one_line

Record = Callable[[ChatRequest, ChatResult | None, str | None], None]
Polled = tuple[float, ChatResult | None, str | None, float]  # (stamp, result, error, latency [s])


class ThreadWorker:
    """Realtime mode: runs model calls in a thread; the controller only polls.

    A model error comes back as that call's error. Anything else (a bug below the call) ends the thread:
    `died` then names it, so the episode can say its assist failed instead of running on without answers.
    After `close` nothing the thread meets is reported (the episode is over and its backend closed).
    """

    def __init__(self, call: Callable[[ChatRequest], ChatResult]) -> None:
        self._call = call
        self._requests: queue.Queue[tuple[float, ChatRequest] | None] = queue.Queue(maxsize=1)
        self.results: queue.Queue[Polled] = queue.Queue()
        self.died: str | None = None  # what ended the thread before `close`, one line
        self._closed = threading.Event()
        self._thread = threading.Thread(target=self._run, name="llmnav-fsm-llm", daemon=True)
        self._thread.start()

    def submit(self, stamp: float, request: ChatRequest) -> None:
        """Send one request (at most one is in flight)."""
        self._requests.put_nowait((stamp, request))

    def poll(self) -> Polled | None:
        """(stamp, result, error, latency [s]) of the next answer, or None when none has arrived."""
        try:
            return self.results.get_nowait()
        except queue.Empty:
            return None

    def _run(self) -> None:
        while True:
            item = self._requests.get()
            if item is None or self._closed.is_set():
                return
            stamp, request = item
            started = time.perf_counter()
            try:
                self.results.put((stamp, self._call(request), None, time.perf_counter() - started))
            except LlmnavError as err:
                self.results.put((stamp, None, str(err), time.perf_counter() - started))
            except Exception as err:  # noqa: BLE001 - a bug below the call: reported, never a thread's traceback
                if not self._closed.is_set():
                    self.died = f"{type(err).__name__}: {one_line(err)}"
                    self.results.put((stamp, None, f"assist failed: {self.died}", time.perf_counter() - started))
                return

    def close(self) -> None:
        """Stop the thread; a call still running is abandoned (daemon thread), its outcome unreported."""
        self._closed.set()
        with contextlib.suppress(queue.Full):
            self._requests.put_nowait(None)
        self._thread.join(timeout=0.1)


class ProcessWorker:
    """Realtime mode with an in-process engine (`Backend.engine_in_process`): the model in its own process.

    It runs below the loop's priority (llmnav.backends.isolated), and the loop thread itself sends the
    request and polls for the answer between ticks. No other thread of the loop's process runs Python, so the
    loop never waits for the GIL; the `llm_call` event goes through `record`.
    """

    def __init__(self, process: Any, record: Record) -> None:
        self._process = process
        self._record = record
        self._sent: tuple[float, ChatRequest] | None = None

    @classmethod
    def start(cls, backend: Any, schema: dict[str, Any], warm_up: ChatRequest, record: Record) -> ProcessWorker:
        """Start the model's process, check the answer schema there and prime its prompt cache.

        All before the first tick. `warm_up` (its answer is dropped, unlogged) puts the system prompt in
        the new process's prompt cache, as earlier episodes do for a model kept in this process: measured
        at load 8, the first suggestion of a cold process read 285 prompt tokens in 49-59 s.
        The model runs below the loop: ordinary beside a loop that runs real-time (more niceness would
        only make its answers staler, 3-4 s against 0.9 s at load 7), else MODEL_NICE below it.
        """
        nice = MODEL_NICE if available_priority() == "normal" else 0
        process = ModelProcess(backend.spec, backend.options, nice=nice)
        try:
            process.check_schema(schema)
            with contextlib.suppress(LlmnavError):  # a model that cannot answer says so at each suggestion
                process.chat(warm_up)
        except BaseException:
            process.close()
            raise
        return cls(process, record)

    def submit(self, stamp: float, request: ChatRequest) -> None:
        """Send one request (at most one is in flight)."""
        self._sent = (stamp, request)
        self._process.submit(request)

    def poll(self) -> Polled | None:
        """(stamp, result, error, latency [s]) once the answer is there, else None; never waits."""
        reply = self._process.poll()
        if reply is None or self._sent is None:
            return None
        (stamp, request), self._sent = self._sent, None
        result, error, latency = reply
        message = None if error is None else str(error)
        self._record(request, result, message)
        return stamp, result, message, latency

    @property
    def died(self) -> str | None:
        """Why the model's process cannot answer any more (killed, crashed), once it cannot."""
        return getattr(self._process, "dead", None)

    def close(self) -> None:
        """Stop the model's process."""
        self._process.close()
