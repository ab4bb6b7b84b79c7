"""Backend faults: a loopback server that answers one good reply and then fails in one way, driven by a
real `llmnav drive --planner stepwise --backend openai|gemini|ollama` episode.

Properties: retries are bounded (the server sees at most max_retries + 1 attempts per call, one for
faults that are not transient), the run ends "aborted" with a one-line reason naming the fault, within a
bounded time, and the log written up to then is intact (the first step's action, the failed call's
error, the end event; `read_run` and `summarize_run` accept it).

The CLI cannot set HTTP options, so `get_backend` is wrapped to pass short timeouts and backoffs; the
backend, HTTP client, runner and command are the real ones. One case runs the `llmnav` executable with
its default options.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

import llmnav.runs.runner as runner
from llmnav.cli import app
from llmnav.runs.runlog import read_run
from llmnav.scoring.metrics import summarize_run
from llmnav.world.scenario import load_scenario

CATEGORY = "backend faults"
SMALL_ROOM = str(Path(__file__).parents[1] / "runner" / "small_room.yaml")
FAST = {"max_retries": 2, "backoff_base_s": 0.05, "backoff_max_s": 0.1, "timeout_s": 0.5,
        "connect_timeout_s": 0.5, "retry_after_max_s": 2.0}
ATTEMPTS = FAST["max_retries"] + 1
GOOD = (
    '```json\n{"goal": "look", "reasoning": "turn to see", "scene_description": "a room", '
    '"action": {"command": "ROTATE_LEFT", "parameters": 30}}\n```'
)
HTML = "<!DOCTYPE html><html><head><title>502 Bad Gateway</title></head><body><h1>Bad Gateway</h1>" \
    "<p>The upstream server is unavailable.</p>\n<hr><address>nginx</address></body></html>"


def good_body(backend: str, text: str = GOOD) -> dict[str, Any]:
    if backend == "openai":
        return {"choices": [{"message": {"role": "assistant", "content": text}, "finish_reason": "stop"}],
                "model": "m", "usage": {"prompt_tokens": 1, "completion_tokens": 1}}
    if backend == "gemini":
        return {"candidates": [{"content": {"role": "model", "parts": [{"text": text}]},
                                "finishReason": "STOP"}], "usageMetadata": {}}
    return {"model": "m", "message": {"role": "assistant", "content": text}, "done": True}


# kind → (fault factory, attempts the client should make, words the reason must hold)
def fault_table(Fault: Any) -> dict[str, tuple[Callable[[str], Any], int, tuple[str, ...]]]:
    return {
        "timeout": (lambda b: Fault("hang", 200, good_body(b), delay_s=1.5), ATTEMPTS, ("timeout",)),
        "slow body": (lambda b: Fault("slow", 200, good_body(b), delay_s=0.2), ATTEMPTS, ("timeout",)),
        "429 retry-after": (
            lambda b: Fault("ok", 429, {"error": {"message": "rate limited"}}, headers={"Retry-After": "0.3"}),
            ATTEMPTS,
            ("429",),
        ),
        "429 no delay": (lambda b: Fault("ok", 429, {"error": "slow down"}), ATTEMPTS, ("429",)),
        "429 over the wait limit": (
            lambda b: Fault("ok", 429, {"error": "quota"}, headers={"Retry-After": "3600"}),
            1,
            ("429", "limit"),
        ),
        "500": (lambda b: Fault("ok", 500, {"error": {"message": "internal"}}), ATTEMPTS, ("500",)),
        "503": (lambda b: Fault("ok", 503, {"error": {"message": "overloaded"}}), ATTEMPTS, ("503",)),
        "connection reset": (lambda b: Fault("reset"), ATTEMPTS, ("connection",)),
        "truncated body": (lambda b: Fault("truncated", 200, good_body(b)), ATTEMPTS, ("connection",)),
        "non-JSON body": (lambda b: Fault("raw", 200, "this is not json", "text/plain"), 1, ("JSON",)),
        "JSON without the answer": (lambda b: Fault("ok", 200, {"object": "list", "data": []}), 1, ("reply",)),
        "HTML 502 page": (lambda b: Fault("raw", 502, HTML, "text/html"), ATTEMPTS, ("502",)),
        "HTML 404 page": (lambda b: Fault("raw", 404, HTML.replace("502 Bad Gateway", "404"), "text/html"),
                          1, ("404",)),
    }


QUICK = ["timeout", "429 retry-after", "503", "connection reset", "HTML 502 page", "non-JSON body"]


def backend_spec(backend: str, url: str, monkeypatch: pytest.MonkeyPatch) -> str:
    if backend == "openai":
        monkeypatch.setenv("OPENAI_API_KEY", "sk-test-fault-key")
        return f"openai:m@{url}/v1"
    if backend == "gemini":
        monkeypatch.setenv("GEMINI_API_KEY", "gemini-test-fault-key")
        monkeypatch.setenv("LLMNAV_GEMINI_BASE_URL", url)
        return "gemini:gemini-2.0-flash"
    monkeypatch.setenv("OLLAMA_HOST", url)
    return "ollama:llama3.1"


def fast_backends(monkeypatch: pytest.MonkeyPatch) -> None:
    real = runner.get_backend

    def with_fast_http(spec: str, **options: Any) -> Any:
        return real(spec, **{**FAST, **options})

    monkeypatch.setattr(runner, "get_backend", with_fast_http)


def run_fault(
    kind: str, backend: str, tmp_path: Path, server: Any, kit: dict[str, Any], monkeypatch: Any, tally: Any
) -> None:
    make, attempts, words = fault_table(kit["Fault"])[kind]
    fast_backends(monkeypatch)
    spec = backend_spec(backend, server.url, monkeypatch)
    server.push(kit["Fault"]("ok", 200, good_body(backend)))  # step 1 succeeds
    fault = make(backend)
    server.default = fault
    out = tmp_path / f"{backend}-{kind.replace(' ', '_')}"
    started = time.perf_counter()
    result = CliRunner().invoke(
        app,
        ["drive", "--planner", "stepwise", "--backend", spec, "--scenario", SMALL_ROOM, "--task-id", "T1",
         "--sensing", "lidar", "--out", str(out), "--json"],
    )
    elapsed = time.perf_counter() - started
    tally.add(CATEGORY, tried=1)
    tally.note_add(CATEGORY, "kinds", kind)
    tally.note_add(CATEGORY, "backends", backend)
    problems = []
    if result.exception is not None and not isinstance(result.exception, SystemExit):
        problems.append(f"raised {type(result.exception).__name__}: {result.exception}")
        tally.add(CATEGORY, crashes=1)
    try:
        record = read_run(out)
        summarize_run(record, load_scenario(SMALL_ROOM))
    except Exception as err:  # noqa: BLE001
        tally.add(CATEGORY, lost=1)
        raise AssertionError(f"{backend}/{kind}: log unreadable: {err}; output {result.output}") from err
    if not record.complete or record.summary is None:
        tally.add(CATEGORY, lost=1)
        problems.append("log has no end event or no summary.json")
    summary = json.loads(result.stdout)
    reason = str(summary.get("reason"))
    calls = record.of_type("llm_call")
    actions = record.of_type("action")
    fault_calls = len(server.seen) - 1
    if result.exit_code != 4 or summary["outcome"] != "aborted":
        problems.append(f"exit {result.exit_code}, outcome {summary['outcome']}")
    if "\n" in reason or reason.startswith("crash") or not all(w.lower() in reason.lower() for w in words):
        problems.append(f"reason {reason!r} lacks {words}")
    if fault_calls != attempts:
        problems.append(f"server saw {fault_calls} attempts after the good reply, expected {attempts}")
    if [a["command"] for a in actions] != ["ROTATE_LEFT"] or "reply" not in calls[0]:
        problems.append(f"the first step's action was lost: {actions}")
    if "error" not in calls[-1] or "\n" in calls[-1]["error"]:
        problems.append(f"the failed call is not logged with a one-line error: {calls[-1]}")
    # bounded: the attempts' timeouts and waits, plus the episode's own work
    if elapsed > attempts * (1.5 + FAST["timeout_s"]) + 15:
        problems.append(f"took {elapsed:.1f} s")
    assert not problems, (backend, kind, problems, result.output[-800:])


@pytest.mark.parametrize("kind", QUICK)
def test_fault_aborts_cleanly_quick(
    kind: str, tmp_path: Path, fault_server: Any, fault_kit: Any, monkeypatch: Any, tally: Any
) -> None:
    run_fault(kind, "openai", tmp_path, fault_server, fault_kit, monkeypatch, tally)


# Every fault kind on every backend, except the openai cases the quick subset already runs.
FULL_CASES = [
    (kind, backend)
    for backend in ("openai", "gemini", "ollama")
    for kind in fault_table(object)
    if not (backend == "openai" and kind in QUICK)
]


@pytest.mark.slow
@pytest.mark.reliability
@pytest.mark.parametrize(("kind", "backend"), FULL_CASES)
def test_fault_aborts_cleanly_full(
    kind: str, backend: str, tmp_path: Path, fault_server: Any, fault_kit: Any, monkeypatch: Any, tally: Any
) -> None:
    run_fault(kind, backend, tmp_path, fault_server, fault_kit, monkeypatch, tally)


def test_html_error_page_with_the_real_executable(
    tmp_path: Path, fault_server: Any, fault_kit: Any, tally: Any
) -> None:
    """The `llmnav` program with its default HTTP options: a 404 HTML page is not retried."""
    Fault = fault_kit["Fault"]
    fault_server.push(Fault("ok", 200, good_body("openai")))
    fault_server.default = Fault("raw", 404, HTML.replace("502 Bad Gateway", "404 Not Found"), "text/html")
    out = tmp_path / "html404"
    env = {k: v for k, v in os.environ.items() if not k.endswith("_API_KEY")}
    proc = subprocess.run(
        [str(Path(sys.executable).parent / "llmnav"), "drive", "--planner", "stepwise", "--backend",
         f"openai:m@{fault_server.url}/v1", "--scenario", SMALL_ROOM, "--task-id", "T1",
         "--sensing", "lidar", "--out", str(out), "--quiet"],
        capture_output=True, text=True, timeout=120, env=env,
    )
    tally.add(CATEGORY, tried=1)
    tally.note_add(CATEGORY, "kinds", "HTML 404 page (CLI defaults)")
    record = read_run(out)
    summary = record.summary or {}
    assert proc.returncode == 4, proc.stderr
    assert "Traceback" not in proc.stdout + proc.stderr
    assert summary["outcome"] == "aborted" and "HTTP 404" in summary["reason"]
    assert "1 attempt" in summary["reason"] and "\n" not in summary["reason"]
    assert "<" not in summary["reason"] and "Bad Gateway" in summary["reason"]  # words, not markup
    assert len(fault_server.seen) == 2 and record.complete
    assert [a["command"] for a in record.of_type("action")] == ["ROTATE_LEFT"]


@pytest.mark.slow
@pytest.mark.reliability
def test_connection_refused_with_the_real_executable(tmp_path: Path, tally: Any) -> None:
    """The `llmnav` program with its default HTTP options against a port nobody listens on."""
    import socket

    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    port = sock.getsockname()[1]
    sock.close()
    out = tmp_path / "refused"
    env = {k: v for k, v in os.environ.items() if not k.endswith("_API_KEY")}
    started = time.perf_counter()
    proc = subprocess.run(
        [str(Path(sys.executable).parent / "llmnav"), "drive", "--planner", "stepwise", "--backend",
         f"openai:m@http://127.0.0.1:{port}/v1", "--scenario", SMALL_ROOM, "--task-id", "T1",
         "--sensing", "lidar", "--out", str(out), "--quiet"],
        capture_output=True, text=True, timeout=120, env=env,
    )
    elapsed = time.perf_counter() - started
    tally.add(CATEGORY, tried=1)
    tally.note_add(CATEGORY, "kinds", "connection refused (CLI defaults)")
    record = read_run(out)
    summary = record.summary or {}
    assert proc.returncode == 4, proc.stderr
    assert "Traceback" not in proc.stdout + proc.stderr
    assert summary["outcome"] == "aborted" and "connection failed" in summary["reason"]
    assert "5 attempts" in summary["reason"] and "\n" not in summary["reason"]
    assert record.complete and len(record.of_type("llm_call")) == 1
    # default backoff: 4 retries with ceilings 1, 2, 4, 8 s, each drawn in [1/2, 1] of its ceiling
    assert elapsed < 60, elapsed
