"""A backend in a process of its own (`ModelProcess`): the same answers and errors as in process, calls that
never block on the model, the priority it was given, and a child that dies answering with an error, not a hang.

The child rebuilds the backend from its spec; the null policy `policy:first` stands in for a model (no
weights to load), and a missing GGUF file for a model that cannot start.
"""

from __future__ import annotations

import os
import signal
import time

import pytest

from llmnav.backends.base import ChatRequest, Message, get_backend
from llmnav.backends.isolated import ModelProcess
from llmnav.errors import ModelError, ModelUnavailableError
from llmnav.planners.fsm.answers import velocity_schema

REQUEST = ChatRequest((Message("user", "stop 1.00 +0.00 45 -150"),), json_schema=velocity_schema(0.0, 0.06, 0.8))


def poll_until_answered(process: ModelProcess, timeout_s: float = 30.0) -> tuple[object, object, float]:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        reply = process.poll()
        if reply is not None:
            return reply
        time.sleep(0.005)
    raise AssertionError("no answer")


def test_answers_like_the_backend_in_process_and_polls_without_blocking() -> None:
    with ModelProcess("policy:first") as process:
        assert process.poll() is None  # nothing in flight
        in_process = get_backend("policy:first").chat(REQUEST)
        assert process.chat(REQUEST).text == in_process.text
        process.check_schema(REQUEST.json_schema or {})
        started = time.perf_counter()
        process.submit(REQUEST)
        first = process.poll()  # returns at once, answered or not
        assert time.perf_counter() - started < 0.5
        result, error, took = first or poll_until_answered(process)
        assert error is None and getattr(result, "text", None) == in_process.text and took >= 0.0


def test_a_backend_that_cannot_start_raises_its_own_error() -> None:
    with pytest.raises(ModelUnavailableError, match="not found"):
        ModelProcess("local:/nonexistent/model.gguf")


@pytest.mark.skipif(not hasattr(os, "getpriority"), reason="POSIX priorities")
def test_the_child_runs_at_the_niceness_asked_for() -> None:
    mine = os.getpriority(os.PRIO_PROCESS, 0)
    with ModelProcess("policy:first", nice=3) as process:
        assert os.getpriority(os.PRIO_PROCESS, process.pid) == min(19, mine + 3)


def test_a_child_that_died_answers_with_an_error_not_a_hang() -> None:
    process = ModelProcess("policy:first")
    try:
        os.kill(process.pid, signal.SIGKILL)
        process.submit(REQUEST)
        result, error, _ = poll_until_answered(process)
        assert result is None and isinstance(error, ModelError) and "ended" in str(error)
        with pytest.raises(ModelError, match="ended"):
            process.chat(REQUEST)
    finally:
        process.close()


def test_a_child_that_stops_answering_is_given_up_not_waited_for(monkeypatch: pytest.MonkeyPatch) -> None:
    from llmnav.backends import isolated

    monkeypatch.setattr(isolated, "CALL_TIMEOUT_S", 0.5)
    process = ModelProcess("policy:first")
    try:
        os.kill(process.pid, signal.SIGSTOP)  # alive, but never answers
        with pytest.raises(ModelError, match="no answer"):
            process.chat(REQUEST)
        process.submit(REQUEST)  # no "already in flight": a late answer is never taken for this one
        result, error, _ = poll_until_answered(process, timeout_s=2.0)
        assert result is None and isinstance(error, ModelError)
    finally:
        os.kill(process.pid, signal.SIGCONT)
        process.close()
