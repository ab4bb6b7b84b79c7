"""Exclusive folder locks: one writer per ablation folder and per run folder, across processes.

A lock is `fcntl.flock` on a small file holding the holder's pid. The kernel releases it when the holder's
process dies however it dies (SIGKILL included), so a stale lock file never blocks anyone; the file itself
stays. A second process does not wait: it gets a one-line `FolderLockedError` naming the holder's pid.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

from llmnav.errors import BadInputError, FolderLockedError

try:
    import fcntl
except ImportError:  # not POSIX: no cross-process lock (documented; the rest still works)
    fcntl = None  # type: ignore[assignment]

LOCK_FILE = ".llmnav.lock"


_NOFOLLOW = getattr(os, "O_NOFOLLOW", 0)
_NONBLOCK = getattr(os, "O_NONBLOCK", 0)  # a FIFO under the lock's name must not block the probe


def _holder(path: Path) -> str:
    try:
        fd = os.open(path, os.O_RDONLY | os.O_CLOEXEC | _NOFOLLOW | _NONBLOCK)
        with os.fdopen(fd, "rb") as handle:
            text = handle.read(32).decode("ascii", errors="replace").strip()
    except OSError:
        text = ""
    return f"pid {text}" if text.isdigit() else "another process"


class FolderLock:
    """An exclusive lock on `folder` (created when missing), held until `release()` or process exit."""

    def __init__(self, folder: Path, what: str) -> None:
        self.path = Path(folder) / LOCK_FILE
        self._fd: int | None = None
        try:
            Path(folder).mkdir(parents=True, exist_ok=True)
            # never through a link planted under the lock's name (it would be truncated and overwritten)
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC | _NOFOLLOW, 0o644)
            if not stat.S_ISREG(os.fstat(fd).st_mode):
                os.close(fd)
                raise OSError(0, f"{LOCK_FILE} is not a regular file")
        except OSError as err:
            if os.path.islink(self.path):
                raise BadInputError(
                    f"{folder}: {LOCK_FILE} is a symbolic link, not a lock llmnav made; remove it to use this folder"
                ) from None
            raise BadInputError(f"{folder}: cannot create {what}: {err.strerror or err}") from None
        if fcntl is not None:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                os.close(fd)
                raise FolderLockedError(
                    f"{folder} is in use: {_holder(self.path)} is writing this {what}; wait for it or "
                    "choose another --out"
                ) from None
        os.ftruncate(fd, 0)
        os.write(fd, str(os.getpid()).encode())
        self._fd = fd

    def release(self) -> None:
        """Give the lock up (closing the file releases it)."""
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None

    def __enter__(self) -> FolderLock:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


def locked_by(folder: Path) -> str | None:
    """Who holds `folder`'s lock right now ("pid N"), or None when nobody does (never blocks)."""
    path = Path(folder) / LOCK_FILE
    if fcntl is None or not path.exists():
        return None
    try:
        fd = os.open(path, os.O_RDONLY | os.O_CLOEXEC | _NOFOLLOW | _NONBLOCK)
    except OSError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except OSError:
        return _holder(path)
    finally:
        os.close(fd)  # closing drops the shared lock taken for the probe
    return None
