"""Run logs: one JSONL file per episode, every event flushed the moment it happens.

Layout of a run folder: `run.jsonl` (first line the configuration, then one event per line),
`summary.json` (written at the end, atomically), `images/<sha256>.jpg` (each image sent, once),
`trajectory.png`. A process killed at any moment leaves a log whose complete lines are all valid;
`read_run` ignores a torn last line.

Event vocabulary (field `type`; every event also has `t_wall` [s since start] and, when known, `t_sim` [s]):
- `config`       first line: versions, scenario, task, start pose, planner, backend spec, who bills it
                 (`billing`, llmnav.backends.prices), options, seed, prompt-template hashes.
- `observation`  what the planner saw: `step`, `pose`, `odom`, `lidar_front_m`, `lidar_text`, `detections`,
                 `image` (sha256 or absent).
- `llm_call`     `step`, `purpose` (action | correction | veto | self_check | ground | waypoints |
                 suggestion | choice), `cache` (hit | miss | off: the reply cache, `--cache`), `request`
                 (ChatRequest.to_log()), `reply` (ChatResult.to_log()) or `error` (one line).
- `guard`        `step`, `outcome` (ok | parse | schema | bounds | veto), `error`, `attempt`, and `value`
                 (the accepted answer as JSON data, or None).
- `action`       `step`, `command`, `parameters`, `pose_before`, `pose_after`, `collided`, `collision_with`,
                 `stopped_reason`; `vetoed` and `veto` for a motion the layer refused; `distance_m`,
                 `rotated_deg`, `duration_s` where measured (one form: `llmnav.guard.legs.Action`).
- `pose`         a trajectory sample: `pose` [x, y, yaw]. Path length and final pose come from these.
- `localize`     the pose a planner believes (sensed information): `pose` [x, y, yaw], and for a scan
                 matched to its map `accepted`, `matched` (share of points on the map), `points`, `reason`.
                 The summary's `pose_error_m` scores it against the `pose` sample before it.
- `planner`      planner-specific records (waypoint plans and verdicts, FSM tick statistics, suggestions).
- `end`          `outcome` (completed | failed | aborted), `reason`.

Any event may carry `truncated`: a list of {field, chars, sha256} for strings longer than MAX_TEXT_CHARS,
which are logged as their head and tail only (a model may answer megabytes; corrections re-send it).
A run folder is written by one process at a time (a lock file, `llmnav.runs.locking`) and must be new or empty.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from llmnav.core.chat import Image
from llmnav.core.geometry import logged_pose
from llmnav.core.safefiles import LOG_LIMIT, SUMMARY_LIMIT, UnsafeFileError, read_text, write_bytes, write_text
from llmnav.core.safefiles import loads as bounded_loads
from llmnav.errors import BadInputError, FolderLockedError, RunFolderError, expand_secrets
from llmnav.runs.locking import LOCK_FILE, FolderLock, locked_by

RUN_FILE = "run.jsonl"
SUMMARY_FILE = "summary.json"
IMAGES_DIR = "images"
SUPERSEDED_FILE = "superseded.json"  # an ablation's mark on a kept folder that holds no result (see ablate)


def _json_default(value: object) -> object:
    if hasattr(value, "tolist"):  # numpy scalars and arrays
        return value.tolist()
    if hasattr(value, "model_dump"):
        return value.model_dump(mode="json")
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


def _clean(value: Any) -> Any:
    """Replace non-finite floats by strings so every line is strict JSON."""
    if isinstance(value, float) and not math.isfinite(value):
        return "inf" if value > 0 else ("-inf" if value < 0 else "nan")
    if isinstance(value, dict):
        return {k: _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    return value


def dumps(record: dict[str, Any]) -> str:
    """One strict-JSON line."""
    return json.dumps(_clean(record), default=_json_default, ensure_ascii=False, allow_nan=False)


def check_new_run_folder(run_dir: Path) -> None:
    """Refuse a run folder that holds a run or anything else (a user's own files are never overwritten)."""
    run_dir = Path(run_dir)
    if (run_dir / RUN_FILE).exists():
        raise BadInputError(f"{run_dir} already holds a run ({RUN_FILE}); choose another --out")
    if run_dir.exists() and not run_dir.is_dir():
        raise BadInputError(f"{run_dir}: not a folder; choose another --out")
    try:
        entries = list(run_dir.iterdir()) if run_dir.exists() else []
    except OSError as err:
        raise BadInputError(f"cannot read run folder {run_dir}: {err.strerror or err}") from None
    # what a run killed in its first instant leaves behind is not the user's: it may be reused
    ours = {LOCK_FILE, RUN_FILE + ".tmp"}
    foreign = sorted(
        p.name for p in entries if p.name not in ours and not (p.name == IMAGES_DIR and not any(p.iterdir()))
    )
    if foreign:
        shown = ", ".join(foreign[:3]) + (", ..." if len(foreign) > 3 else "")
        raise BadInputError(f"{run_dir} is not empty (holds {shown}); choose a new or empty --out")


# Logged text per string: a model may answer megabytes, and every correction request re-sends the answer.
# Longer strings keep their head and tail; the event lists what was cut with the full length and hash.
MAX_TEXT_CHARS = 64_000
_HEAD_CHARS, _TAIL_CHARS = 48_000, 8_000


def cap_text(record: dict[str, Any]) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """The record with every string longer than MAX_TEXT_CHARS cut to head + marker + tail, and the cuts."""
    cut: list[dict[str, Any]] = []

    def walk(value: Any, where: str) -> Any:
        if isinstance(value, str):
            if len(value) <= MAX_TEXT_CHARS:
                return value
            digest = hashlib.sha256(value.encode("utf-8", "surrogatepass")).hexdigest()
            cut.append({"field": where, "chars": len(value), "sha256": digest})
            marker = f"\n[... {len(value) - _HEAD_CHARS - _TAIL_CHARS} characters not logged ...]\n"
            return value[:_HEAD_CHARS] + marker + value[-_TAIL_CHARS:]
        if isinstance(value, dict):
            return {k: walk(v, f"{where}.{k}" if where else str(k)) for k, v in value.items()}
        if isinstance(value, (list, tuple)):
            return [walk(v, f"{where}[{i}]") for i, v in enumerate(value)]
        return value

    capped = walk(record, "")
    return (capped if cut else record), cut


def write_json_atomic(path: Path, data: dict[str, Any]) -> None:
    """Write JSON via a fresh temporary file and rename, so readers never see half a file (links not followed)."""
    write_text(path, json.dumps(_clean(data), default=_json_default, indent=2, allow_nan=False) + "\n")


class RunLog:
    """Append-only writer of one run folder."""

    def __init__(self, run_dir: Path, config: dict[str, Any], *, secrets: Iterable[str] = ()) -> None:
        self.run_dir = Path(run_dir)
        self._given: tuple[str, ...] = ()
        self._secrets: tuple[str, ...] = ()
        self.redact(secrets)  # before the first line: the configuration names the backend
        holder = locked_by(self.run_dir)
        if holder is not None:  # another process is writing it: say who, before anything else
            raise FolderLockedError(f"{self.run_dir} is in use: {holder} is writing this run folder")
        check_new_run_folder(self.run_dir)
        # One writer per run folder: a second process (two drives with the same --out) stops at once.
        self._folder_lock = FolderLock(self.run_dir, "run folder")
        # The log is born under a temporary name and linked to run.jsonl once its first line is written:
        # a process killed in between leaves no run.jsonl without its configuration, and the link fails
        # if run.jsonl appeared meanwhile (exists-then-create is one atomic step).
        partial = self.run_dir / (RUN_FILE + ".tmp")
        try:
            check_new_run_folder(self.run_dir)  # again, now that the folder is ours
            (self.run_dir / IMAGES_DIR).mkdir(parents=True, exist_ok=True)
            # A lone surrogate (a model answer may carry "\ud800" escapes) cannot be UTF-8: written as the
            # same JSON escape it came from, the line stays valid JSON instead of the write raising.
            # A leftover partial (a run killed in its first instant) is ours to remove; the new one is created
            # exclusively and never through a link someone planted under its name.
            if os.path.lexists(partial):
                os.unlink(partial)
            fd = os.open(partial, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0), 0o644)
            self._file = os.fdopen(fd, "w", encoding="utf-8", errors="backslashreplace")
        except OSError as err:
            self._folder_lock.release()
            raise BadInputError(f"cannot write run folder {self.run_dir}: {err.strerror or err}") from None
        except BaseException:
            self._folder_lock.release()
            raise
        self._t0 = time.perf_counter()
        self._images: set[str] = set()
        self._lock = threading.Lock()  # a model worker thread may log while the control loop does
        self.sim_time: float | None = None
        self.write_error: str | None = None  # the first failed write (disk full): nothing is written after it
        self.listeners: list[Callable[[dict[str, Any]], None]] = []  # each event as logged (a live view)
        self._write({"type": "config", **config})
        if self.write_error is not None:
            self.close()
            raise RunFolderError(f"{self.run_dir}: {self.write_error}")
        try:
            os.link(partial, self.run_dir / RUN_FILE)
        except FileExistsError:
            self.close()
            partial.unlink(missing_ok=True)
            raise BadInputError(f"{self.run_dir} already holds a run ({RUN_FILE}); choose another --out") from None
        except OSError:  # a file system without hard links: the folder lock already excludes other writers
            os.replace(partial, self.run_dir / RUN_FILE)
        else:
            os.unlink(partial)

    def redact(self, secrets: Iterable[str]) -> None:
        """Replace these strings (a backend's key, URL credentials) by `***` in every line written from now."""
        self._given = (*self._given, *secrets)
        self._secrets = expand_secrets(self._given)  # every form it may take, longest first

    def _write(self, record: dict[str, Any]) -> str:
        """Append the record as one line; returns the line (capped, secrets redacted)."""
        record, cut = cap_text(record)
        if cut:
            record["truncated"] = cut
        line = dumps(record) + "\n"
        for secret in self._secrets:  # a server may echo the key back: it is never logged, wherever it is
            line = line.replace(secret, "***")
        with self._lock:
            if self._file.closed or self.write_error:  # a late model call, or the disk is full
                return line
            try:
                self._file.write(line)
                self._file.flush()  # survives SIGKILL: the line is in the kernel's page cache
            except OSError as err:  # the log keeps its complete lines (a torn last one is ignored)
                self.write_error = f"cannot write {RUN_FILE}: {err.strerror or err}"
        return line

    def event(self, type_: str, **fields: Any) -> None:
        """Append one event (flushed at once)."""
        record: dict[str, Any] = {"type": type_, "t_wall": round(time.perf_counter() - self._t0, 4)}
        if self.sim_time is not None and "t_sim" not in fields:
            record["t_sim"] = round(self.sim_time, 4)
        record.update(fields)
        line = self._write(record)
        if self.listeners:  # they see the event as logged: capped, secrets redacted
            logged = json.loads(line)
            for listener in self.listeners:
                listener(logged)

    def image(self, image: Image) -> str:
        """Store an image once beside the log; returns its hash."""
        digest = image.sha256
        if digest not in self._images:
            path = self.run_dir / IMAGES_DIR / f"{digest}.jpg"
            if not path.exists():
                try:
                    write_bytes(path, image.jpeg_bytes)
                except OSError as err:  # no event will name it: the log stops here
                    self.write_error = self.write_error or f"cannot write {path.name}: {err.strerror or err}"
                    return digest
            self._images.add(digest)
        return digest

    def write_summary(self, summary: dict[str, Any]) -> Path:
        """Write `summary.json` atomically (RunFolderError when it cannot be written)."""
        path = self.run_dir / SUMMARY_FILE
        try:
            write_json_atomic(path, summary)
        except OSError as err:
            raise RunFolderError(
                f"{self.run_dir}: cannot write {SUMMARY_FILE}: {err.strerror or err}; {RUN_FILE} is complete"
            ) from None
        return path

    def check_written(self) -> None:
        """Raise RunFolderError if a write failed (the log is readable up to the failure)."""
        if self.write_error is not None:
            raise RunFolderError(f"{self.run_dir}: {self.write_error}; the log is readable up to that point")

    def close(self) -> None:
        """Close the log file and give up the folder lock."""
        with self._lock:
            if not self._file.closed:
                try:
                    self._file.close()
                except OSError:  # the flush of a failed write fails again: already recorded
                    pass
        self._folder_lock.release()

    def __enter__(self) -> RunLog:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@dataclass
class RunRecord:
    """A run folder as read back: configuration, events, and whether it ended properly."""

    run_dir: Path
    config: dict[str, Any]
    events: list[dict[str, Any]] = field(default_factory=list)
    summary: dict[str, Any] | None = None
    torn_lines: int = 0  # incomplete trailing lines ignored (a killed run)

    @property
    def complete(self) -> bool:
        """Whether the run reached its `end` event."""
        return any(e.get("type") == "end" for e in self.events)

    def of_type(self, type_: str) -> list[dict[str, Any]]:
        """Events of one type, in order."""
        return [e for e in self.events if e.get("type") == type_]

    def poses(self) -> list[list[float]]:
        """The trajectory: every logged `pose` sample with finite numbers, in order (others count as missing)."""
        poses = (logged_pose(e.get("pose")) for e in self.events if e.get("type") == "pose")
        return [p for p in poses if p is not None]


def read_run(run_dir: Path) -> RunRecord:
    """Read a run folder (complete or cut short); raise BadInputError if it is no run folder."""
    path = Path(run_dir) / RUN_FILE
    try:  # a FIFO, /dev/zero or a link out of the folder is refused, not waited on or read without end
        text = read_text(path, limit=LOG_LIMIT, root=Path(run_dir))
    except UnsafeFileError:
        raise
    except OSError:
        raise BadInputError(f"{run_dir}: not a run folder (no {RUN_FILE})") from None
    lines = text.split("\n")
    records: list[dict[str, Any]] = []
    torn = 0
    for number, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        try:
            record = bounded_loads(line)
        except json.JSONDecodeError:
            if number >= len(lines) - 1:  # only the last line may be torn by a kill
                torn += 1
                continue
            raise BadInputError(f"{path}: line {number}: not valid JSON") from None
        if not isinstance(record, dict) or "type" not in record:
            raise BadInputError(f"{path}: line {number}: not a run-log event")
        records.append(record)
    if not records or records[0].get("type") != "config":
        raise BadInputError(f"{path}: first line is not the run configuration")
    summary = read_summary(Path(run_dir))
    return RunRecord(Path(run_dir), records[0], records[1:], summary, torn)


def read_summary(run_dir: Path) -> dict[str, Any] | None:
    """A run's summary.json, or None when it is missing, damaged, no regular file in the folder, or too large."""
    try:
        summary = bounded_loads(read_text(run_dir / SUMMARY_FILE, limit=SUMMARY_LIMIT, root=run_dir))
    except (ValueError, OSError, UnsafeFileError):
        return None
    return summary if isinstance(summary, dict) else None
