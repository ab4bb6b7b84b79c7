"""Against llama.cpp's real HTTP server: `llmnav serve` with the bundled SmolLM2, driven through `openai`.

One server for the module (`llmnav serve --port 0` as a subprocess, with a key), on 127.0.0.1 only.
Episodes are one decision long to keep the suite short. The server is text-only, as the model is, so
this is also the test of the text-only handling against the server's own rejection.
Measured: 76 s at load average 16 (two decisions of 20-30 s there); a decision costs a few seconds on a
quiet machine.
"""

from __future__ import annotations

import json
import os
import queue
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import httpx
import pytest
from typer.testing import CliRunner

from llmnav.backends.http import forget_text_only
from llmnav.cli import app
from llmnav.runs.runlog import read_run

LLMNAV = str(Path(sys.executable).parent / "llmnav")
KEY = "serve-test-key-5f2a9c"
LOAD_TIMEOUT_S = 300.0  # [s] model load under heavy load took 15 s; be generous, it fails loudly anyway


@dataclass
class Served:
    process: subprocess.Popen[str]
    url: str
    backend: str


def _read_lines(process: subprocess.Popen[str], count: int, timeout_s: float) -> list[str]:
    """The first `count` stdout lines, read by a thread (a buffered pipe defeats select)."""
    assert process.stdout is not None
    stdout = process.stdout
    lines: queue.Queue[str] = queue.Queue()
    threading.Thread(target=lambda: [lines.put(line) for line in stdout], daemon=True).start()
    got: list[str] = []
    deadline = time.monotonic() + timeout_s
    while len(got) < count:
        try:
            got.append(lines.get(timeout=max(0.0, deadline - time.monotonic())).strip())
        except queue.Empty:
            if process.poll() is not None:
                stderr = process.stderr.read() if process.stderr else ""
                raise AssertionError(f"serve ended early (exit {process.returncode}): {stderr[-2000:]}") from None
            raise AssertionError(f"llmnav serve printed {got} within {timeout_s} s") from None
    return got


@pytest.fixture(scope="module")
def served() -> Iterator[Served]:
    env = {**os.environ, "LLMNAV_API_KEY": KEY}
    process = subprocess.Popen(
        [LLMNAV, "serve", "--port", "0", "--ctx", "4096"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    try:
        url, backend_flag = _read_lines(process, 2, LOAD_TIMEOUT_S)
        assert backend_flag.startswith("--backend openai:local@"), backend_flag
        yield Served(process, url, backend_flag.removeprefix("--backend "))
    finally:
        # Ctrl-C stops it cleanly: exit 0 and a last status line; a failure here errors the module.
        process.send_signal(signal.SIGINT)
        try:
            _, stderr = process.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            process.kill()
            raise
    assert process.returncode == 0, stderr[-2000:]
    assert stderr.strip().splitlines()[-1] == "server stopped"


@pytest.fixture(autouse=True)
def _client_key(monkeypatch):
    monkeypatch.setenv("OPENAI_API_KEY", KEY)  # what the openai backend sends as its Bearer token
    monkeypatch.setenv("COLUMNS", "200")
    forget_text_only()


def _drive(out: Path, backend: str, *args: str) -> tuple[int, str, str]:
    result = CliRunner().invoke(
        app, ["drive", "--task", "Go to room 101", "--backend", backend, "--out", str(out), "--quiet", *args]
    )
    return result.exit_code, result.stdout, result.stderr


def test_serves_on_loopback_only_and_wants_its_key(served, listening):
    port = int(served.url.rsplit(":", 1)[1].split("/")[0])
    addresses = listening(served.process.pid)
    assert ("127.0.0.1", port) in addresses
    assert {ip for ip, _ in addresses} == {"127.0.0.1"}, addresses
    assert httpx.get(f"{served.url}/models", timeout=10).status_code == 401
    listed = httpx.get(f"{served.url}/models", headers={"Authorization": f"Bearer {KEY}"}, timeout=10)
    assert [m["id"] for m in listed.json()["data"]] == ["local"]


def test_a_second_server_on_the_same_port_is_one_line_exit_2(served):
    port = served.url.rsplit(":", 1)[1].split("/")[0]
    done = subprocess.run([LLMNAV, "serve", "--port", port], capture_output=True, text=True, timeout=120)
    assert done.returncode == 2
    assert done.stderr.strip() == f"error: port {port} on 127.0.0.1 is already in use: choose another with --port"
    assert done.stdout == ""


def test_check_sees_a_text_only_server_that_honours_schemas(served):
    result = CliRunner().invoke(app, ["backends", "--check", served.backend])
    lines = {line[4:].split(":")[0]: line for line in result.stdout.splitlines()}
    assert result.exit_code == 1, result.output
    for name in ("reachable", "models listed", "model present", "accepts a JSON Schema"):
        assert lines[name].startswith("ok"), result.output
    assert lines["accepts images"].startswith("no") and "text-only" in lines["accepts images"]
    assert lines["scores continuations"].startswith("ok"), result.output


def test_the_server_scores_like_the_in_process_engine(served):
    """The same model, scored over HTTP (`/tokenize`, `/completions`) and in process: the same numbers."""
    from llmnav.backends.base import get_backend
    from llmnav.backends.local import LocalBackend
    from llmnav.core.chat import ScoreRequest

    request = ScoreRequest("Task: Go to the window\nThe robot drives to the", (" window", " room 104", " stairs"))
    remote = get_backend(served.backend)
    try:
        assert remote.can_score
        over_http = remote.score(request).scores
    finally:
        remote.close()
    in_process = LocalBackend().score(request).scores
    assert [s.tokens for s in over_http] == [s.tokens for s in in_process]
    for a, b in zip(over_http, in_process, strict=True):
        assert a.logprob == pytest.approx(b.logprob, abs=0.05)
    assert max(range(3), key=lambda i: over_http[i].logprob) == 0  # " window" after a task naming it


def test_hybrid_scores_over_http_reaches_the_room_and_replays(served, tmp_path):
    out = tmp_path / "scored"
    code, stdout, stderr = _drive(out, served.backend, "--max-iterations", "5")
    assert code == 0, stdout + stderr
    record = read_run(out)
    assert [e["decide"] for e in record.of_type("planner")] == ["score"]
    assert all(c["purpose"] == "score" for c in record.of_type("llm_call"))
    again = tmp_path / "again"
    code_again, _, _ = _drive(again, f"replay:{out}", "--max-iterations", "5")
    first, second = (json.loads((d / "summary.json").read_text()) for d in (out, again))
    assert code_again == 0 and second["final_pose"] == first["final_pose"]


def test_check_with_lidar_sensing_passes_a_text_only_server(served):
    result = CliRunner().invoke(app, ["backends", "--check", served.backend, "--sensing", "lidar"])
    lines = {line[4:].split(":")[0]: line for line in result.stdout.splitlines()}
    assert result.exit_code == 0, result.output
    assert lines["accepts images"].startswith("–") and "not needed with --sensing lidar" in lines["accepts images"]
    assert "text-only" in lines["accepts images"]  # the finding is still shown
    # a run that does send images is still judged on them
    with_images = CliRunner().invoke(app, ["backends", "--check", served.backend, "--sensing", "lidar,image"])
    assert with_images.exit_code == 1, with_images.output


@pytest.mark.parametrize("planner", ["hybrid", "stepwise"])
def test_default_sensing_stops_at_once_with_the_hint(served, tmp_path, planner):
    out = tmp_path / planner
    # The hybrid asks for a generated choice here: scored decisions send no image (see the scoring test).
    extra = ("--decide", "generate") if planner == "hybrid" else ()
    code, stdout, stderr = _drive(out, served.backend, "--planner", planner, *extra)
    assert code == 2
    line = stderr.strip()
    assert "\n" not in line and "takes no images" in line and "--sensing lidar" in line, stderr
    assert "score" not in stdout
    record = read_run(out)  # the run folder is kept, its log closed with the reason
    end = record.of_type("end")[0]
    assert end["outcome"] == "aborted" and "takes no images" in end["reason"]
    assert len(record.of_type("llm_call")) <= 1  # stopped at the first rejection


def test_hybrid_drop_images_goes_on_and_replays_strictly(served, tmp_path, caplog):
    out = tmp_path / "hybrid"
    with caplog.at_level("WARNING"):  # the one line on screen (stderr outside pytest's log capture)
        code, stdout, stderr = _drive(
            out, served.backend, "--drop-images", "--max-iterations", "1", "--decide", "generate"
        )
    record = read_run(out)
    calls = record.of_type("llm_call")
    assert code in (0, 1), stderr
    assert [r.getMessage() for r in caplog.records if "takes no images" in r.getMessage()] == [
        f"{served.backend.split('@')[0]} at {served.url} takes no images: going on without them (--drop-images)"
    ]
    assert calls and all(c["reply"]["meta"]["images_dropped"] == 1 for c in calls), calls
    assert calls[0]["request"]["messages"][-1]["images"]  # the log keeps what the planner asked to send
    assert record.config["options"]["drop_images"] is True
    assert record.of_type("end")[0]["outcome"] in ("completed", "failed"), stdout

    replay = tmp_path / "replay"
    code_again, _, stderr_again = _drive(
        replay, f"replay:{out / 'run.jsonl'}", "--drop-images", "--max-iterations", "1", "--decide", "generate"
    )
    assert code_again == code, stderr_again
    first, again = (json.loads((d / "summary.json").read_text()) for d in (out, replay))
    assert (again["outcome"], again["final_pose"]) == (first["outcome"], first["final_pose"])


def test_stepwise_with_lidar_only(served, tmp_path):
    out = tmp_path / "stepwise"
    args = ("--planner", "stepwise", "--sensing", "lidar", "--prompt", "short", "--max-iterations", "1")
    code, _, stderr = _drive(out, served.backend, *args)
    record = read_run(out)
    calls = record.of_type("llm_call")
    assert code in (0, 1), stderr
    assert calls and all("reply" in c and "images_dropped" not in c["reply"]["meta"] for c in calls), calls
    assert not any(m.get("images") for c in calls for m in c["request"]["messages"])
    assert all(c["reply"]["model"] == "local" for c in calls)
    replay = tmp_path / "replay"
    assert _drive(replay, f"replay:{out / 'run.jsonl'}", *args)[0] == code
    assert len(read_run(replay).of_type("llm_call")) == len(calls)
