"""The control loop's scheduling: SCHED_FIFO for the block where permitted, the nice fallback where not,
the previous policy back afterwards, and threads started inside at ordinary priority."""

from __future__ import annotations

import os
import threading

import pytest

from llmnav import realtime
from llmnav.realtime import realtime_priority

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
