"""`llmnav ablate --ray local`: a real private Ray on loopback, as a user runs it (the CLI in a subprocess).

The episodes use the oracle (no model) and the hybrid planner through the `openai` backend against a
scripted loopback server that wants a key, so they are short and the key's journey is visible.
Starting Ray costs 5-25 s here (more under load): one real-Ray test is in the default suite, the
interrupt/resume and failing-backend ones are marked slow.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from ipaddress import ip_address
from pathlib import Path
from typing import Any

import pytest

from llmnav.ablate import ray_tasks
from llmnav.errors import BadInputError

pytest.importorskip("ray", reason="the optional extra llmnav[ray] is not installed (make installs it for tests)")

LLMNAV = str(Path(sys.executable).parent / "llmnav")
SMALL_ROOM = Path(__file__).parents[1] / "runner" / "small_room.yaml"
KEY = "sk-ray-test-key-0c1d2e3f"
ANSWER = {"option": 1, "reasoning": "the first option"}


class KeyServer:
    """An OpenAI-style loopback server: answers hybrid choices to requests carrying KEY, 401 to others."""

    def __init__(self, delay_s: float = 0.0) -> None:
        self.authorizations: list[str] = []
        self.fail = False  # answer 401 to everyone (a backend that fails)
        server = self

        class Handler(BaseHTTPRequestHandler):
            def do_POST(self) -> None:  # noqa: N802
                self.rfile.read(int(self.headers.get("Content-Length") or 0))
                auth = self.headers.get("Authorization", "")
                server.authorizations.append(auth)
                time.sleep(delay_s)
                ok = auth == f"Bearer {KEY}" and not server.fail
                body = (
                    {"choices": [{"message": {"role": "assistant", "content": json.dumps(ANSWER)}}], "model": "m"}
                    if ok
                    else {"error": {"message": "invalid key", "type": "authentication_error"}}
                )
                payload = json.dumps(body).encode()
                self.send_response(200 if ok else 401)
                self.send_header("Content-Type", "application/json")
                self.send_header("Content-Length", str(len(payload)))
                self.end_headers()
                self.wfile.write(payload)

            def log_message(self, *args: Any) -> None:
                pass

        self.httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.httpd.server_address[1]}/v1"
        threading.Thread(target=self.httpd.serve_forever, daemon=True).start()

    def close(self) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()


@pytest.fixture
def closed_port() -> int:
    """A loopback port nothing listens on."""
    import socket

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


@pytest.fixture
def key_server():
    server = KeyServer()
    yield server
    server.close()


def _grid(tmp_path: Path, url: str, *, poses: str = "[1, 2]", trials: int = 1) -> Path:
    scenario = tmp_path / "small_room.yaml"  # a custom scenario file: it must travel as content
    shutil.copy(SMALL_ROOM, scenario)
    grid = tmp_path / "grid.yaml"
    grid.write_text(
        f"scenario: {scenario}\ntasks: [T1]\nposes: {poses}\ntrials: {trials}\n"
        f"planner: [oracle, hybrid]\nbackend: ['openai:m@{url}']\nsensing: [lidar]\n"
        "options: {max_iterations: 1}\n"
    )
    return grid


def _env(**extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.endswith("_API_KEY") and not k.startswith("RAY_")}
    return {**env, "COLUMNS": "200", **extra}


def _manifest(folder: Path) -> dict[str, Any]:
    return json.loads((folder / "manifest.json").read_text())


def _loopback(address: str) -> bool:
    ip = ip_address(address)
    mapped = getattr(ip, "ipv4_mapped", None)
    return ip.is_loopback or (mapped is not None and mapped.is_loopback)


def _ablate(grid: Path, out: Path, *args: str, env: dict[str, str], listening=None, timeout: float = 600):
    """Run the CLI; with `listening`, sample the listening sockets of its whole process tree meanwhile."""
    process = subprocess.Popen(
        [LLMNAV, "ablate", "--grid", str(grid), "--out", str(out), *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    seen: set[tuple[str, int]] = set()
    deadline = time.monotonic() + timeout
    while process.poll() is None and time.monotonic() < deadline:
        if listening is not None:
            seen.update(listening(process.pid))
        time.sleep(0.3)
    stdout, stderr = process.communicate(timeout=max(1.0, deadline - time.monotonic()))
    return process.returncode, stdout, stderr, seen


def test_ray_local_equals_workers_1_keeps_to_loopback_and_carries_the_key(key_server, tmp_path, listening):
    grid = _grid(tmp_path, key_server.url)
    home = tmp_path / "home"  # the user's home: a private Ray must leave nothing there (no ~/.ray/auth_token)
    home.mkdir()
    env = _env(OPENAI_API_KEY=KEY, HOME=str(home))
    started = time.time()
    code, stdout, stderr, seen = _ablate(grid, tmp_path / "ray", "--ray", "local", env=env, listening=listening)
    assert code == 0, stderr[-3000:]
    assert list(home.rglob("*")) == []
    assert "Token authentication" not in stderr and " INFO " not in stderr and " WARNING " not in stderr, stderr
    assert seen, "no Ray process was seen listening: the loopback check saw nothing"
    assert all(_loopback(ip) for ip, _ in seen), sorted(seen)

    ray_requests = len(key_server.authorizations)
    assert ray_requests >= 2 and set(key_server.authorizations) == {f"Bearer {KEY}"}  # the key reached the tasks
    code_serial, _, stderr_serial, _ = _ablate(grid, tmp_path / "serial", "--workers", "1", env=env)
    assert code_serial == 0, stderr_serial[-3000:]

    by_ray, serial = _manifest(tmp_path / "ray"), _manifest(tmp_path / "serial")
    assert by_ray["size"] == serial["size"] == 4 and by_ray["done"] == serial["done"] == 4
    for a, b in zip(by_ray["episodes"], serial["episodes"], strict=True):
        assert (a["key"], a["status"], a["outcome"], a["score"]) == (b["key"], b["status"], b["outcome"], b["score"])
        ray_summary = json.loads((tmp_path / "ray" / a["dir"] / "summary.json").read_text())
        serial_summary = json.loads((tmp_path / "serial" / b["dir"] / "summary.json").read_text())
        assert ray_summary["final_pose"] == serial_summary["final_pose"]
        assert ray_summary["run_dir"] == str(tmp_path / "ray" / a["dir"])  # written on the driver's disk
    # No file of the sweep holds the key, and Ray's own folder for this sweep (sessions, logs) is gone.
    for path in (tmp_path / "ray").rglob("*"):
        if path.is_file():
            assert KEY.encode() not in path.read_bytes(), path
    tmp = Path(tempfile.gettempdir())
    assert not [p for p in tmp.glob("llmnav-ray-*") if p.stat().st_mtime >= started - 1]
    for path in (tmp / "ray").rglob("*.log") if (tmp / "ray").is_dir() else ():
        if path.stat().st_mtime >= started:
            assert KEY.encode() not in path.read_bytes(), path


def test_unreachable_address_is_one_line_exit_2(tmp_path, closed_port):
    grid = _grid(tmp_path, "http://127.0.0.1:9/v1")
    started = time.monotonic()
    code, stdout, stderr, _ = _ablate(
        grid, tmp_path / "x", "--ray", f"127.0.0.1:{closed_port}", env=_env(), timeout=120
    )
    assert code == 2 and stderr.strip().count("\n") == 0, stderr
    assert f"--ray 127.0.0.1:{closed_port}: cannot reach the Ray cluster" in stderr
    assert time.monotonic() - started < 60  # refused at once, not after Ray's minute of retries


def test_ray_not_installed_is_bad_input(monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)
    with pytest.raises(BadInputError, match=r"pip install 'llmnav\[ray\]'"):
        ray_tasks.connect("auto")


def test_task_environment_forwards_settings_and_caps_threads():
    environ = {
        "OPENAI_API_KEY": "k1",
        "GEMINI_API_KEY": "k2",
        "OLLAMA_HOST": "http://h:1",
        "OPENAI_BASE_URL": "http://b/v1",
        "LLMNAV_LOCAL_THREADS": "3",
        "HOME": "/root",
        "PATH": "/bin",
        "AWS_SECRET": "not ours",
    }
    cpus, env, keys = ray_tasks.task_env("local", environ)
    assert cpus == 3 and env["LLMNAV_LOCAL_THREADS"] == "3" and env["OMP_NUM_THREADS"] == "1"
    assert {k for k in env if k in environ} == {"OLLAMA_HOST", "OPENAI_BASE_URL", "LLMNAV_LOCAL_THREADS"}
    # keys never go into the runtime env (Ray's runtime-env agent logs it): they travel as an argument
    assert keys == {"OPENAI_API_KEY": "k1", "GEMINI_API_KEY": "k2"}
    cpus_http, env_http, _ = ray_tasks.task_env("openai:m@http://x/v1", environ)
    assert cpus_http == 1 and env_http["LLMNAV_LOCAL_THREADS"] == "1"


def test_failing_backend_is_an_error_and_retried_on_resume(key_server, tmp_path):
    grid = _grid(tmp_path, key_server.url, poses="[1]")
    out = tmp_path / "ray"
    key_server.fail = True
    code, stdout, stderr, _ = _ablate(grid, out, "--ray", "local", env=_env(OPENAI_API_KEY=KEY))
    manifest = _manifest(out)
    hybrid = [e for e in manifest["episodes"] if "hybrid" in e["key"]]
    assert [e["status"] for e in hybrid] == ["error"], stdout + stderr
    assert "401" in hybrid[0]["error"] and manifest["done"] == 1

    key_server.fail = False
    failed_requests = len(key_server.authorizations)
    code, stdout, stderr, _ = _ablate(grid, out, "--ray", "local", env=_env(OPENAI_API_KEY=KEY))
    assert code == 0, stderr[-3000:]
    assert _manifest(out)["done"] == 2 and len(key_server.authorizations) > failed_requests


@pytest.mark.slow
def test_sigint_then_resume(tmp_path):
    slow = KeyServer(delay_s=2.0)
    try:
        grid = _grid(tmp_path, slow.url, poses="[1, 2]", trials=3)
        out = tmp_path / "ray"
        env = _env(OPENAI_API_KEY=KEY)
        process = subprocess.Popen(
            [LLMNAV, "ablate", "--grid", str(grid), "--out", str(out), "--ray", "local"],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=env,
        )
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline and process.poll() is None:
            manifest_path = out / "manifest.json"
            if manifest_path.exists() and json.loads(manifest_path.read_text())["done"] >= 1:
                break
            time.sleep(0.3)
        process.send_signal(signal.SIGINT)
        _, stderr = process.communicate(timeout=120)
        assert process.returncode == 130, stderr[-3000:]
        interrupted = _manifest(out)
        assert 1 <= interrupted["done"] < interrupted["size"] == 12
        done_before = {e["key"]: e["dir"] for e in interrupted["episodes"] if e["status"] == "done"}

        code, _, stderr, _ = _ablate(grid, out, "--ray", "local", env=env)
        assert code == 0, stderr[-3000:]
        resumed = _manifest(out)
        assert resumed["done"] == 12
        for entry in resumed["episodes"]:  # finished episodes were kept, not run again
            if entry["key"] in done_before:
                assert entry["dir"] == done_before[entry["key"]]
    finally:
        slow.close()


def test_returned_files_land_inside_the_run_folder_summary_last(tmp_path):
    summary = {"outcome": "completed", "run_dir": "/tmp/llmnav-task-x/ep", "trajectory": "/tmp/llmnav-task-x/ep/t.png"}
    task = ray_tasks.TaskResult(
        (summary, None, False),
        {
            "summary.json": json.dumps(summary).encode(),
            "run.jsonl": b'{"type": "config"}\n',
            "images/a.jpg": b"\xff\xd8",
            "../escape.txt": b"no",
        },
        node="n1",
        workdir="/tmp/llmnav-task-x/ep",
    )
    run_dir = tmp_path / "out" / "ep"
    ray_tasks.write_files(task, run_dir)
    assert sorted(str(p.relative_to(run_dir)) for p in run_dir.rglob("*") if p.is_file()) == [
        "images/a.jpg", "run.jsonl", "summary.json",
    ]  # fmt: skip
    assert not (tmp_path / "out" / "escape.txt").exists()
    written = json.loads((run_dir / "summary.json").read_text())
    assert written["run_dir"] == str(run_dir) and written["trajectory"] == str(run_dir / "t.png")
    assert (run_dir / "summary.json").stat().st_mtime_ns >= (run_dir / "run.jsonl").stat().st_mtime_ns
