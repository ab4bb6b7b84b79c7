"""A thread's scheduling for a control loop that must keep its deadline on a machine others are using.

`realtime_priority()` runs the calling thread under SCHED_FIFO for a block, where the system permits it
(Linux with CAP_SYS_NICE or an RLIMIT_RTPRIO, as in most containers run as root): no ordinary process can
then preempt it, however loaded the cores are. Where it is not permitted, the thread's nice value is
raised instead where that is permitted, else nothing changes; the block learns which it got. The
previous policy is restored on exit. `SCHED_RESET_ON_FORK` keeps processes and threads started inside the
block at ordinary priority: only the loop itself runs first.

The model's threads are deliberately left at ordinary priority rather than niced: they hold the GIL
between calls into llama.cpp, and a niced holder on a busy core would make the loop wait for the GIL
(priority inversion) longer than any preemption it saves.
"""

from __future__ import annotations

import contextlib
import os
import threading
from collections.abc import Iterator

FIFO_PRIORITY = 10  # of 1..99: above every ordinary process, below the kernel's own real-time threads
NICE_BOOST = 5  # the fallback: this much above the thread's nice value


@contextlib.contextmanager
def realtime_priority(priority: int = FIFO_PRIORITY) -> Iterator[str]:
    """Run the calling thread at real-time priority for the block; yields "fifo", "nice-5" or "normal"."""
    policy = getattr(os, "SCHED_FIFO", None)
    if policy is None:  # not Linux
        yield "normal"
        return
    saved_policy, saved_param = os.sched_getscheduler(0), os.sched_getparam(0)
    tid = threading.get_native_id()
    saved_nice = os.getpriority(os.PRIO_PROCESS, tid)
    got = "normal"
    try:
        os.sched_setscheduler(0, policy | getattr(os, "SCHED_RESET_ON_FORK", 0), os.sched_param(priority))
        got = "fifo"
    except OSError:  # not permitted: try a higher nice priority
        try:
            os.setpriority(os.PRIO_PROCESS, tid, saved_nice - NICE_BOOST)
            got = f"nice-{NICE_BOOST}"
        except OSError:
            pass
    try:
        yield got
    finally:
        if got == "fifo":
            os.sched_setscheduler(0, saved_policy, saved_param)
        elif got != "normal":
            os.setpriority(os.PRIO_PROCESS, tid, saved_nice)
