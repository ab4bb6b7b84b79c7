"""A thread's scheduling for a control loop that must keep its deadline on a machine others are using.

`realtime_priority()` runs the calling thread under SCHED_FIFO for a block, where the system permits it
(Linux with CAP_SYS_NICE or an RLIMIT_RTPRIO, as in most containers run as root): no ordinary process can
then preempt it, however loaded the cores are. Where it is not permitted, the thread's nice value is
raised instead where that is permitted, else nothing changes; the block learns which it got. The
previous policy is restored on exit. `SCHED_RESET_ON_FORK` keeps processes and threads started inside the
block at ordinary priority: only the loop itself runs first.

Anything the loop waits for must not run at ordinary priority on a busy core, or the loop waits as long
as that thread is preempted (priority inversion): the GIL held by another thread of the process, a
helper thread of a native library. So a model that computes inside the process runs in a process of its
own below the loop's priority (llmnav.backends.isolated), the simulator casts its rays in the calling
thread, and `frozen_heap()` keeps the garbage collector from scanning the whole heap during a tick.
`available_priority()` tells beforehand what the loop will get.
"""

from __future__ import annotations

import contextlib
import gc
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


def available_priority() -> str:
    """What `realtime_priority()` would give a thread here ("fifo", "nice-5" or "normal"), changing nothing.

    Probed on a throwaway thread, so a helper process can be placed below the loop before the loop starts.
    """
    found: list[str] = []

    def probe() -> None:
        with realtime_priority() as got:
            found.append(got)

    thread = threading.Thread(target=probe, name="llmnav-priority-probe")
    thread.start()
    thread.join()
    return found[0] if found else "normal"


@contextlib.contextmanager
def frozen_heap() -> Iterator[None]:
    """Collect now, then exempt every object alive from the garbage collector's scans for the block.

    A full collection over an episode's heap (simulator, model client, modules) took 20-28 ms inside one
    tick; objects made before the clock starts live on, so scanning them again finds nothing. Objects
    made inside the block are collected as usual; the exempt ones rejoin the collector afterwards.
    """
    gc.collect()
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()
