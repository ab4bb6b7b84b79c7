"""Files in folders a user (or anyone sharing the machine) may have prepared: written and read without surprises.

Writes go to a fresh temporary file made with `O_CREAT|O_EXCL|O_NOFOLLOW` in the target's folder and are
renamed into place: a planted `view.html.tmp → ~/.bashrc` is never opened, and the rename replaces a link
at the target itself rather than writing through it. Reads take regular files only (a FIFO would block
forever, `/dev/zero` never ends) that stay inside the folder they belong to (an `images/x.jpg →
~/.ssh/id_rsa` is not embedded in a page meant for sharing), up to a size cap. JSON from a file or a
server is parsed with a nesting limit, so a `[` × 200,000 is a one-line error instead of a RecursionError.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import secrets
import shutil
import stat
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

from llmnav.errors import BadInputError

MAX_JSON_DEPTH = 64  # llmnav's own records nest about 8 deep; servers' replies about 6
LOG_LIMIT = 512 << 20  # [bytes] a run.jsonl (a long FSM run logs tens of MB)
SUMMARY_LIMIT = 16 << 20  # [bytes] a summary.json or manifest.json
IMAGE_LIMIT = 8 << 20  # [bytes] one camera image (640×480 JPEGs are ~50 kB)
_NOFOLLOW = getattr(os, "O_NOFOLLOW", 0)
_NONBLOCK = getattr(os, "O_NONBLOCK", 0)  # opening a FIFO for reading must not wait for a writer
_CLOEXEC = getattr(os, "O_CLOEXEC", 0)


class UnsafeFileError(BadInputError):
    """A file is not a regular file inside its folder, or is too large."""


class JsonLimitError(json.JSONDecodeError):
    """JSON over the nesting or size limit (a JSONDecodeError, so callers' handlers of bad JSON take it)."""

    def __init__(self, message: str) -> None:
        super().__init__(message, "", 0)
        self.message = message

    def __str__(self) -> str:
        return self.message


# --- writing -------------------------------------------------------------------------------------


def _fresh(folder: Path, name: str) -> tuple[int, Path]:
    """A new file in `folder` that nobody else can have prepared (exclusive create, links not followed)."""
    for _ in range(100):
        tmp = folder / f".{name}.{secrets.token_hex(4)}.tmp"
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | _NOFOLLOW | _CLOEXEC, 0o644)
        except FileExistsError:
            continue
        return fd, tmp
    raise FileExistsError(f"{folder}: no free temporary name")


def write_bytes(path: Path, data: bytes) -> Path:
    """Write `data` to `path` atomically; a link at `path` is replaced, never written through (OSError)."""
    path = Path(path)
    fd, tmp = _fresh(path.parent, path.name)
    try:
        with os.fdopen(fd, "wb") as handle:
            handle.write(data)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    return path


def write_text(path: Path, text: str) -> Path:
    """`write_bytes` of UTF-8 text."""
    return write_bytes(path, text.encode("utf-8", "surrogateescape"))


@contextlib.contextmanager
def atomic_text(path: Path) -> Iterator[IO[str]]:
    """A text file written in steps and renamed onto `path` when done (`write_bytes` for a stream).

    Nothing is left at `path` or beside it when the writing fails; a link at `path` is replaced.
    """
    path = Path(path)
    fd, tmp = _fresh(path.parent, path.name)
    try:
        with os.fdopen(fd, "w", encoding="utf-8", errors="surrogateescape", newline="") as handle:
            yield handle
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


@contextlib.contextmanager
def private_dir(folder: Path) -> Iterator[Path]:
    """A new folder only this process can enter (mode 0700) inside `folder`, removed afterwards.

    For files written by libraries that take a path, not a descriptor (OpenCV's and Pillow's video
    writers): written here, then renamed into place with `os.replace`.
    """
    tmp = Path(tempfile.mkdtemp(prefix=".llmnav-", dir=folder))
    try:
        yield tmp
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


# --- reading -------------------------------------------------------------------------------------


def _inside(path: Path, root: Path) -> bool:
    try:
        return path.resolve().is_relative_to(root.resolve())
    except (OSError, RuntimeError):  # a link loop
        return False


def read_bytes(path: Path, *, limit: int, root: Path | None = None, what: str | None = None) -> bytes:
    """The bytes of a regular file of at most `limit` bytes that lies (links resolved) inside `root`.

    FileNotFoundError when it does not exist; UnsafeFileError (a one-line BadInputError) when it is a
    FIFO, device, folder, link out of `root` (or any link when no `root` is given) or too large.
    """
    path = Path(path)
    name = what or str(path)
    target = path
    if root is not None:
        if not _inside(path, root):
            if not os.path.lexists(path):
                raise FileNotFoundError(path)
            raise UnsafeFileError(f"{name}: leads out of {root}; not read")
        target = path.resolve()  # a link inside the folder is followed once, here
    try:
        fd = os.open(target, os.O_RDONLY | _NOFOLLOW | _NONBLOCK | _CLOEXEC)
    except OSError as err:
        if os.path.islink(target):
            raise UnsafeFileError(f"{name}: is a symbolic link; not read") from None
        if isinstance(err, FileNotFoundError):
            raise
        raise UnsafeFileError(f"{name}: cannot read: {err.strerror or err}") from None
    with os.fdopen(fd, "rb") as handle:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            raise UnsafeFileError(f"{name}: not a regular file (a FIFO, device or folder); not read")
        if info.st_size > limit:
            raise UnsafeFileError(f"{name}: {info.st_size} bytes, over the {limit} a file of its kind may hold")
        data = handle.read(limit + 1)  # a file growing meanwhile still stops at the cap
    if len(data) > limit:
        raise UnsafeFileError(f"{name}: over the {limit} bytes a file of its kind may hold")
    return data


def read_text(path: Path, *, limit: int, root: Path | None = None, what: str | None = None) -> str:
    """`read_bytes` decoded as UTF-8 (undecodable bytes replaced)."""
    return read_bytes(path, limit=limit, root=root, what=what).decode("utf-8", errors="replace")


def image_kind(data: bytes) -> str | None:
    """'jpeg' or 'png' by the file's signature, else None (what is embedded must be the picture it claims)."""
    if data.startswith(b"\xff\xd8\xff"):
        return "jpeg"
    if data.startswith(b"\x89PNG\r\n\x1a\n"):
        return "png"
    return None


PAGE_GENERATOR = "llmnav view"  # a page's <meta name="generator">: how llmnav knows the pages it wrote
_PAGE_MARK = f'<meta name="generator" content="{PAGE_GENERATOR}">'.encode()


def is_our_page(path: Path) -> bool:
    """Whether an existing file is a page `llmnav view` wrote (its head carries the generator tag).

    Only a regular file, never one reached through a link or a FIFO (which would block the read).
    """
    try:
        fd = os.open(path, os.O_RDONLY | _NOFOLLOW | _NONBLOCK | _CLOEXEC)
    except OSError:
        return False
    with os.fdopen(fd, "rb") as handle:
        return stat.S_ISREG(os.fstat(fd).st_mode) and _PAGE_MARK in handle.read(4096)


# --- JSON ----------------------------------------------------------------------------------------

_STRING = re.compile(r'"(?:[^"\\]|\\.)*"', re.DOTALL)
_NOT_BRACKET = re.compile(r"[^\[\]{}]+")


def json_depth(text: str, stop: int | None = None) -> int:
    """How deep the brackets of a JSON text nest (brackets inside strings do not count), up to `stop`."""
    depth = deepest = 0
    for ch in _NOT_BRACKET.sub("", _STRING.sub("", text)):
        depth += 1 if ch in "[{" else -1
        if depth > deepest:
            deepest = depth
            if stop is not None and deepest >= stop:
                break
    return deepest


def loads(text: str | bytes, *, max_depth: int = MAX_JSON_DEPTH, max_bytes: int | None = None) -> Any:
    """`json.loads` with a nesting and a size limit; JsonLimitError (a one-line message) when over either.

    A text with fewer brackets than `max_depth` cannot nest deeper and is not scanned.
    """
    if max_bytes is not None and len(text) > max_bytes:
        raise JsonLimitError(f"JSON of {len(text)} bytes, over the limit of {max_bytes}")
    if isinstance(text, bytes):
        text = text.decode("utf-8")
    if text.count("[") + text.count("{") > max_depth and json_depth(text, stop=max_depth + 1) > max_depth:
        raise JsonLimitError(f"JSON nested deeper than {max_depth} levels")
    try:
        return json.loads(text)
    except RecursionError:  # the interpreter's own limit is lower still: same answer
        raise JsonLimitError(f"JSON nested deeper than {max_depth} levels") from None
