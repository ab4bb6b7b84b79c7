"""The control loop's scheduling: SCHED_FIFO for the block where permitted, the nice fallback where not,
the previous policy back afterwards, and threads started inside at ordinary priority; what the loop will
get, told beforehand; a heap the collector leaves alone; no helper thread for the loop to wait on."""

from __future__ import annotations

import gc
import os
import subprocess
import sys
import threading

import pytest

from llmnav.core import realtime
from llmnav.core.realtime import realtime_priority

pytestmark = pytest.mark.skipif(not hasattr(os, "SCHED_FIFO"), reason="POSIX real-time scheduling (Linux)")


def _fifo_permitted() -> bool:
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
    except OSError:
        return False
    os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    return True


def test_the_block_runs_fifo_and_restores_the_policy() -> None:
    if not _fifo_permitted():
        pytest.skip("SCHED_FIFO not permitted here (the fallback is tested below)")
    before = os.sched_getscheduler(0)
    seen: dict[str, int] = {}

    def child() -> None:
        seen["policy"] = os.sched_getscheduler(0)

    with realtime_priority() as got:
        assert got == "fifo"
        assert os.sched_getscheduler(0) & ~getattr(os, "SCHED_RESET_ON_FORK", 0) == os.SCHED_FIFO
        assert os.sched_getparam(0).sched_priority == realtime.FIFO_PRIORITY
        thread = threading.Thread(target=child)
        thread.start()
        thread.join()
    assert seen["policy"] == os.SCHED_OTHER  # a thread started inside (a model's) stays ordinary
    assert os.sched_getscheduler(0) == before


def test_without_permission_the_thread_gets_a_nice_boost_or_nothing(monkeypatch: pytest.MonkeyPatch) -> None:
    def refuse(*_: object) -> None:
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    tid = threading.get_native_id()
    before = os.getpriority(os.PRIO_PROCESS, tid)
    with realtime_priority() as got:
        if got == "normal":  # raising priority is not permitted either
            assert os.getpriority(os.PRIO_PROCESS, tid) == before
        else:
            assert got == f"nice-{realtime.NICE_BOOST}"
            assert os.getpriority(os.PRIO_PROCESS, tid) == before - realtime.NICE_BOOST
    assert os.getpriority(os.PRIO_PROCESS, tid) == before
    monkeypatch.setattr(os, "setpriority", refuse)
    with realtime_priority() as got:
        assert got == "normal"


def test_available_priority_tells_what_the_loop_will_get_and_changes_nothing() -> None:
    before = (os.sched_getscheduler(0), os.getpriority(os.PRIO_PROCESS, threading.get_native_id()))
    predicted = realtime.available_priority()
    assert (os.sched_getscheduler(0), os.getpriority(os.PRIO_PROCESS, threading.get_native_id())) == before
    with realtime_priority() as got:
        assert got == predicted


def test_the_heap_alive_before_the_block_is_left_out_of_collections_inside_it() -> None:
    kept = [[] for _ in range(1000)]  # containers the collector tracks
    with realtime.frozen_heap():
        assert gc.get_freeze_count() >= len(kept)
    assert gc.get_freeze_count() == 0


def test_a_lidar_scan_starts_no_helper_thread() -> None:
    """The loop would wait for a helper at ordinary priority (Bullet's ray threads did: 10-17 ms under load)."""
    code = (
        "import os\n"
        "from llmnav.world.scenario import load_scenario\n"
        "from llmnav.sim.world import World\n"
        "world = World(load_scenario('maze_arena'), seed=0)\n"
        "before = len(os.listdir('/proc/self/task'))\n"
        "world.lidar.scan(); world.lidar.scan(half_angle=0.6)\n"
        "print(before, len(os.listdir('/proc/self/task')))\n"
    )
    if not os.path.isdir("/proc/self/task"):
        pytest.skip("counts threads through /proc")
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}  # numpy's own pool is not the point here
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True)
    before, after = out.stdout.split()[-2:]
    assert after == before
