"""Where episodes run: in this process or in a spawn process pool (Ray tasks: `ray_tasks`); each yields its result."""

from __future__ import annotations

import ctypes
import multiprocessing
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Generator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from typing import TYPE_CHECKING, Any

from llmnav.backends.local import THREADS_ENV, pool_threads
from llmnav.errors import BadInputError, LlmnavError, one_line
from llmnav.runs.runner import run_episode

if TYPE_CHECKING:
    from llmnav.ablate.grid import Episode
    from llmnav.runs.runner import EpisodeSpec

Runner = Callable[["EpisodeSpec"], dict[str, Any]]
Result = tuple[dict[str, Any] | None, str | None, bool]


class WorkerDiedError(LlmnavError):
    """A pool worker ended without an answer (killed, out of memory): the sweep stops, resumable."""


def execute_episode(runner: Runner, spec: EpisodeSpec) -> tuple[dict[str, Any] | None, str | None, bool]:
    """Run one episode in whatever process this is: (summary, error, fatal).

    Bad input (a missing key, an absent model) is fatal: every other episode would fail the same way.
    Any other failure is recorded for this episode and the sweep goes on.
    """
    try:
        return runner(spec), None, False
    except BadInputError as err:
        return None, one_line(err), True
    except Exception as err:  # noqa: BLE001 — one broken episode must not end a long sweep
        text = str(err).splitlines()[0] if str(err) else ""
        return None, f"{type(err).__name__}: {text}" if text else type(err).__name__, False


def default_runner() -> Runner:
    """`llmnav.runs.runner.run_episode`."""
    return run_episode


# Native thread pools a worker might start (BLAS, OpenMP, OpenCV, Mesa's llvmpipe): one thread each, so
# N workers on N cores do not oversubscribe them. Variables the user set win.
_WORKER_THREAD_VARS = (
    "OMP_NUM_THREADS",
    "OPENBLAS_NUM_THREADS",
    "MKL_NUM_THREADS",
    "OPENCV_FOR_THREADS_NUM",
    "LP_NUM_THREADS",
)


def worker_model_threads(workers: int) -> int:
    """Threads for an embedded model in each of `workers` processes (the local backend's measured rule)."""
    return pool_threads(workers)


def init_worker(model_threads: int, parent_pid: int, env: dict[str, str]) -> None:
    """Pool worker start-up, before numpy, cv2 or a model is imported: cap threads, die with the parent.

    `env`: variables for this worker only (where a shared model is served). A `kill -9` of the sweep must
    not leave workers running episodes nobody records.
    """
    for name in _WORKER_THREAD_VARS:
        os.environ.setdefault(name, "1")
    os.environ.setdefault(THREADS_ENV, str(model_threads))
    os.environ.update(env)
    exit_with_parent(parent_pid)


_PR_SET_PDEATHSIG = 1


def exit_with_parent(parent_pid: int, poll_s: float = 0.2) -> None:
    """End this process when `parent_pid` is gone.

    The kernel's parent-death signal on Linux, and a watchdog thread everywhere (it also covers a parent
    that died before the signal was armed).
    """
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
        except (OSError, AttributeError):
            pass

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(poll_s)
        os._exit(1)

    threading.Thread(target=watch, name="llmnav-parent-watchdog", daemon=True).start()


def run_pool(
    runner: Runner, specs: Sequence[tuple[Episode, EpisodeSpec]], workers: int, env: dict[str, str] | None = None
) -> Generator[tuple[Episode, Result], None, None]:
    """Episodes in a spawn process pool (fresh interpreters: no inherited PyBullet or model state).

    `env`: environment variables for the workers alone. A worker that dies (a SIGKILL, the OOM killer) breaks
    the whole pool, and the episodes the others were running die with it: its episode is yielded as an
    error, then `WorkerDiedError` ends the sweep with one line. The manifest keeps every finished
    episode; running the same sweep again resumes it.
    """
    context = multiprocessing.get_context("spawn")
    count = min(workers, len(specs))
    executor = ProcessPoolExecutor(
        max_workers=count,
        mp_context=context,
        initializer=init_worker,
        initargs=(worker_model_threads(count), os.getpid(), dict(env or {})),
    )
    futures: dict[Future[Result], Episode] = {}
    try:
        for ep, spec in specs:
            futures[executor.submit(execute_episode, runner, spec)] = ep
        remaining = set(futures)
        while remaining:
            finished, remaining = wait(remaining, return_when=FIRST_COMPLETED)
            for future in finished:
                try:
                    result = future.result()
                except BrokenProcessPool:
                    episode = futures[future]
                    yield episode, (None, "its worker process died (killed or out of memory)", False)
                    raise WorkerDiedError(
                        f"a worker process died (killed or out of memory) during episode {episode.key}; the "
                        "sweep stopped with the episodes running beside it: run the same command again to "
                        "resume (finished episodes are kept)"
                    ) from None
                yield futures[future], result
    finally:  # Ctrl-C or a fatal episode: drop what has not started, let running episodes end
        executor.shutdown(wait=True, cancel_futures=True)
