"""A dead FSM assist: under `--planner fsm --assist llm --realtime` the model runs in a worker thread. A bug
below the call (anything but a model error) once killed that thread silently: the run went on and was
tabled as `assist=llm` with 0 suggestions, and a reply of `null` printed a thread's traceback. Now odd
replies are model errors (the thread answers on), a thread that dies anyway degrades the run visibly (a
`degraded` event naming the cause, the cause in the end reason and metrics, `assist=llm (failed)` in
every table), and nothing the thread meets after the episode closed its backend is printed ("RuntimeError:
Cannot send a request, as the client has been closed"). Counted as category "dead assist".
"""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from llmnav.backends.openai import OpenAIBackend
from llmnav.cli import app
from llmnav.core.chat import ChatRequest, Message
from llmnav.planners.fsm.workers import ThreadWorker
from llmnav.runs.runlog import read_run

CATEGORY = "dead assist"


@pytest.fixture
def thread_crashes(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """Exceptions that ended a thread (what Python would print as "Exception in thread ...")."""
    seen: list[str] = []
    monkeypatch.setattr(
        threading, "excepthook", lambda args: seen.append(f"{args.exc_type.__name__}: {args.exc_value}")
    )
    return seen


def _fsm(server: Any, out: Path) -> Any:
    args = ["drive", "--planner", "fsm", "--assist", "llm", "--realtime", "--scenario", "maze_arena", "--task-id",
            "M1", "-o", "max_ticks=150", "--backend", f"openai:m@{server.url}/v1",
            "--out", str(out), "--quiet"]  # fmt: skip
    result = CliRunner().invoke(app, args)
    assert result.exit_code in (0, 1, 3), result.output
    return result


def _answers(server: Any, body: Any) -> None:
    def answer(seen: Any) -> Any:
        if seen.path.endswith("/tokenize"):
            return server.reply(404, {"error": "none"})
        return server.reply(200, body, delay_s=0.05)

    server.default = answer


def test_a_null_reply_is_a_model_error_and_the_thread_answers_on(
    tmp_path: Path, server: Any, thread_crashes: list[str], tally: Any
) -> None:
    tally.add(CATEGORY, tried=1)
    _answers(server, "null")  # once an UnboundLocalError below the call: the thread died at the first reply
    _fsm(server, tmp_path / "run")
    metrics = json.loads((tmp_path / "run" / "summary.json").read_text())["planner_metrics"]
    ok = not thread_crashes and metrics["suggestions"] > 1 and metrics["rejected"]["error"] == metrics["suggestions"]
    tally.add(CATEGORY, failures=int(not ok), crashes=len(thread_crashes))
    assert ok, (thread_crashes, metrics)


def test_a_thread_that_dies_degrades_the_run_visibly(
    tmp_path: Path, server: Any, monkeypatch: pytest.MonkeyPatch, thread_crashes: list[str], tally: Any
) -> None:
    tally.add(CATEGORY, tried=1)
    _answers(server, {"choices": [{"message": {"role": "assistant", "content": '{"v": 0, "w": 0}'}}]})

    def broken(self: Any, request: ChatRequest) -> Any:
        raise RuntimeError("a bug below the call")

    monkeypatch.setattr(OpenAIBackend, "chat", broken)
    runs = tmp_path / "runs"
    _fsm(server, runs / "run")
    record = read_run(runs / "run")
    summary = json.loads((runs / "run" / "summary.json").read_text())
    degraded = record.of_type("degraded")
    visible = (
        len(degraded) == 1
        and degraded[0]["cause"] == "RuntimeError: a bug below the call"
        and summary["condition"]["assist"] == "llm (failed)"
        and "assist failed: RuntimeError: a bug below the call" in summary["reason"]
        and summary["planner_metrics"]["assist_failed"] == "RuntimeError: a bug below the call"
    )
    tally.add(CATEGORY, failures=int(not visible), crashes=len(thread_crashes))
    assert visible and not thread_crashes, (degraded, summary["condition"], summary["reason"], thread_crashes)
    table = CliRunner().invoke(app, ["score", str(runs), "--by", "assist"])
    assert table.exit_code == 0 and "assist=llm (failed)" in table.stdout, table.stdout


def test_what_the_thread_meets_after_close_is_not_printed(thread_crashes: list[str], tally: Any) -> None:
    """The episode ended and closed its backend while a call was running: its error is nobody's business."""
    tally.add(CATEGORY, tried=1)
    release = threading.Event()

    def call(request: ChatRequest) -> Any:
        release.wait(5.0)
        raise RuntimeError("Cannot send a request, as the client has been closed.")

    worker = ThreadWorker(call)
    worker.submit(0.0, ChatRequest(messages=(Message("user", "state"),)))
    time.sleep(0.05)
    worker.close()
    release.set()
    worker._thread.join(2.0)
    quiet = not thread_crashes and worker.died is None and worker.poll() is None
    tally.add(CATEGORY, failures=int(not quiet), crashes=len(thread_crashes))
    assert quiet, (thread_crashes, worker.died)


def test_a_dead_model_process_is_reported_as_the_workers_death(tally: Any) -> None:
    """With an in-process engine the model runs in a process of its own; once it is gone, `died` says why."""
    from llmnav.planners.fsm.workers import ProcessWorker

    tally.add(CATEGORY, tried=1)

    class Gone:
        dead = "the model process ended (killed by signal 9)"

    worker = ProcessWorker(Gone(), lambda *_: None)
    named = worker.died == Gone.dead
    tally.add(CATEGORY, failures=int(not named))
    assert named, worker.died
