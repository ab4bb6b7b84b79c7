"""`llmnav ablate --ray 127.0.0.1:PORT` against a Ray head started by hand (`ray start`) on loopback.

The head is started as a user would (`ray start --head --node-ip-address=127.0.0.1`), with token
authentication on because the user's home holds `~/.ray/auth_token` (`ray start` does that by itself).
The driver gets no RAY_* variable: `--ray` must bring the loopback switch and the token mode itself.
Starting the head costs about 10 s here; the sweep is two oracle episodes.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from ipaddress import ip_address
from pathlib import Path

import pytest

pytest.importorskip("ray", reason="the optional extra llmnav[ray] is not installed (make installs it for tests)")

BIN = Path(sys.executable).parent
LLMNAV, RAY = str(BIN / "llmnav"), str(BIN / "ray")
SMALL_ROOM = Path(__file__).parents[1] / "runner" / "small_room.yaml"
JOIN_WITHIN_S = 20.0


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def _env(home: Path) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("RAY_") and not k.endswith("_API_KEY")}
    return {**env, "HOME": str(home), "COLUMNS": "200"}


def _tree(pid: int) -> set[int]:
    """`pid` and every process below it (Linux /proc)."""
    children: dict[int, list[int]] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        children.setdefault(int(fields[1]), []).append(int(stat.parent.name))
    found, todo = set(), [pid]
    while todo:
        current = todo.pop()
        if current not in found:
            found.add(current)
            todo.extend(children.get(current, []))
    return found


def _loopback(address: str) -> bool:
    ip = ip_address(address)
    mapped = getattr(ip, "ipv4_mapped", None)
    return ip.is_loopback or (mapped is not None and mapped.is_loopback)


@pytest.fixture
def head(tmp_path: Path) -> Iterator[tuple[str, Path, subprocess.Popen[str]]]:
    """A token-auth Ray head on 127.0.0.1 (`ray start --block`); (address, the user's home, the process)."""
    home = tmp_path / "home"
    (home / ".ray").mkdir(parents=True)
    (home / ".ray" / "auth_token").write_text("c3a1f0e2d4b6978877665544332211ffeeddccbbaa0099887766554433221100")
    port = _free_port()
    temp = tempfile.mkdtemp(prefix="llmnav-head-")  # short: Ray puts socket paths (at most 107 bytes) in it
    env = {**_env(home), "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0"}  # the user's own choice for the head
    process = subprocess.Popen(
        [RAY, "start", "--head", "--block", "--node-ip-address=127.0.0.1", f"--port={port}",
         "--include-dashboard=false", "--disable-usage-stats", "--num-cpus=2", f"--temp-dir={temp}"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env,
    )  # fmt: skip
    output: list[str] = []
    assert process.stdout is not None
    stdout = process.stdout
    threading.Thread(target=lambda: output.extend(stdout), daemon=True).start()
    deadline = time.monotonic() + 120
    while not any("block forever" in line for line in output):  # `ray start --block` is up and waiting
        assert process.poll() is None and time.monotonic() < deadline, "".join(output)[-3000:]
        time.sleep(0.2)
    try:
        assert "Token authentication is enabled" in "".join(output), "".join(output)[-3000:]
        yield f"127.0.0.1:{port}", home, process
    finally:
        pids = _tree(process.pid)
        process.send_signal(signal.SIGTERM)
        try:
            process.wait(timeout=30)
        except subprocess.TimeoutExpired:
            process.kill()
        for pid in pids - {process.pid}:  # whatever the head left behind
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        shutil.rmtree(temp, ignore_errors=True)


def _grid(tmp_path: Path) -> Path:
    grid = tmp_path / "grid.yaml"
    grid.write_text(
        f"scenario: {SMALL_ROOM}\ntasks: [T1]\nposes: [1, 2]\ntrials: 1\nplanner: [oracle]\nsensing: [lidar]\n"
    )
    return grid


def _ablate(grid: Path, out: Path, env: dict[str, str], *args: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [LLMNAV, "ablate", "--grid", str(grid), "--out", str(out), *args],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
    )  # fmt: skip


def test_a_hand_started_loopback_token_head_is_joined_and_equals_workers_1(head, tmp_path, listening) -> None:
    address, home, head_process = head
    grid = _grid(tmp_path)
    started = time.monotonic()
    sweep = _ablate(grid, tmp_path / "ray", _env(home), "--ray", address)
    seen: set[tuple[str, int]] = set()
    while sweep.poll() is None and time.monotonic() - started < 300:
        seen.update(listening(head_process.pid))
        seen.update(listening(sweep.pid))
        time.sleep(0.3)
    stdout, stderr = sweep.communicate(timeout=60)
    assert sweep.returncode == 0, stderr[-3000:]
    assert "Failed to connect to GCS" not in stderr and "Token authentication" not in stderr, stderr[-3000:]
    assert seen and all(_loopback(ip) for ip, _ in seen), sorted(seen)
    serial = subprocess.run(
        [LLMNAV, "ablate", "--grid", str(grid), "--out", str(tmp_path / "serial"), "--workers", "1"],
        capture_output=True, text=True, env=_env(home), timeout=300,
    )  # fmt: skip
    assert serial.returncode == 0, serial.stderr[-3000:]
    by_ray = json.loads((tmp_path / "ray" / "manifest.json").read_text())
    by_one = json.loads((tmp_path / "serial" / "manifest.json").read_text())
    assert by_ray["done"] == by_one["done"] == 2
    for a, b in zip(by_ray["episodes"], by_one["episodes"], strict=True):
        assert (a["key"], a["status"], a["outcome"], a["score"]) == (b["key"], b["status"], b["outcome"], b["score"])
        ray_summary = json.loads((tmp_path / "ray" / a["dir"] / "summary.json").read_text())
        one_summary = json.loads((tmp_path / "serial" / b["dir"] / "summary.json").read_text())
        assert ray_summary["final_pose"] == one_summary["final_pose"]


def test_a_port_that_answers_but_is_no_ray_cluster_fails_fast(tmp_path) -> None:
    with socket.socket() as mute:  # accepts connections and never speaks
        mute.bind(("127.0.0.1", 0))
        mute.listen()
        address = f"127.0.0.1:{mute.getsockname()[1]}"
        started = time.monotonic()
        done = subprocess.run(
            [LLMNAV, "ablate", "--grid", str(_grid(tmp_path)), "--out", str(tmp_path / "x"), "--ray", address],
            capture_output=True, text=True, env=_env(tmp_path / "home"), timeout=120,
        )  # fmt: skip
        took = time.monotonic() - started
    assert done.returncode == 2, done.stderr[-3000:]
    assert done.stderr.strip().count("\n") == 0, done.stderr
    assert done.stderr.startswith(f"error: --ray {address}: ") and "could be joined" in done.stderr
    assert took < JOIN_WITHIN_S + 5, took
