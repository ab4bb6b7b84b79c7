"""A killed worker: SIGKILL to one worker of `ablate --workers 2` once ended the sweep with a
`BrokenProcessPool` traceback. Now the sweep stops with one line naming the episode, exits non-zero, the
manifest keeps every finished episode, and running the same command again completes the sweep. Counted
as category "worker kill".
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

CATEGORY = "worker kill"
SMALL_ROOM = str(Path(__file__).parents[1] / "runner" / "small_room.yaml")
LLMNAV = str(Path(sys.executable).parent / "llmnav")


def _sweep(out: Path) -> list[str]:
    return [LLMNAV, "ablate", "--scenario", SMALL_ROOM, "--tasks", "T1", "--poses", "1,2", "--trials", "4",
            "--planner", "oracle", "--workers", "2", "--out", str(out)]  # fmt: skip


def _workers(pid: int) -> list[int]:
    """The pool's worker processes below `pid` (spawned interpreters; not the resource tracker)."""
    found = []
    for cmdline in Path("/proc").glob("[0-9]*/cmdline"):
        try:
            text = cmdline.read_bytes().replace(b"\0", b" ").decode()
            parent = int((cmdline.parent / "stat").read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, ValueError, IndexError):
            continue
        if parent == pid and "spawn_main" in text:
            found.append(int(cmdline.parent.name))
    return found


def _statuses(out: Path) -> list[str]:
    try:
        return [e["status"] for e in json.loads((out / "manifest.json").read_text())["episodes"]]
    except (OSError, ValueError, KeyError):
        return []


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_a_killed_worker_stops_the_sweep_in_one_line_and_it_resumes(tmp_path: Path, tally: Any) -> None:
    tally.add(CATEGORY, tried=1)
    out = tmp_path / "sweep"
    proc = subprocess.Popen(_sweep(out), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)  # fmt: skip
    try:
        deadline = time.perf_counter() + 180
        while time.perf_counter() < deadline and proc.poll() is None and "done" not in _statuses(out):
            time.sleep(0.05)  # one finished episode, so the kill lands on a sweep with results to keep
        workers = _workers(proc.pid)
        assert workers and proc.poll() is None, f"no worker to kill: {workers}, exit {proc.poll()}"
        os.kill(workers[0], signal.SIGKILL)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    lines = [line for line in err.splitlines() if line.strip()]
    clean = (
        proc.returncode not in (0, None)
        and "Traceback" not in err
        and "BrokenProcessPool" not in err
        and any(line.startswith("error:") and "worker process died" in line for line in lines)
    )
    tally.add(CATEGORY, failures=int(not clean), crashes=int("Traceback" in err))
    assert clean, (proc.returncode, err[-2000:])
    kept = _statuses(out).count("done")
    assert kept >= 1, _statuses(out)

    again = subprocess.run(_sweep(out), capture_output=True, text=True, timeout=300)
    resumed = again.returncode == 0 and _statuses(out) == ["done"] * 8
    tally.add(CATEGORY, failures=int(not resumed), lost=int(not resumed))
    assert resumed, (again.returncode, again.stderr[-1500:], _statuses(out))
