"""Run logs: one JSONL file per episode, every event flushed the moment it happens.

Layout of a run folder: `run.jsonl` (first line the configuration, then one event per line),
`summary.json` (written at the end, atomically), `images/<sha256>.jpg` (each image sent, once),
`trajectory.png`. A process killed at any moment leaves a log whose complete lines are all valid;
`read_run` ignores a torn last line.

Event vocabulary (field `type`; every event also has `t_wall` [s since start] and, when known, `t_sim` [s]):
- `config`       first line: versions, scenario, task, start pose, planner, backend spec, options, seed,
                 prompt-template hashes.
- `observation`  what the planner saw: `step`, `pose`, `odom`, `lidar_front_m`, `lidar_text`, `detections`,
                 `image` (sha256 or absent).
- `llm_call`     `step`, `purpose` (action | correction | veto | self_check | ground | waypoints |
                 suggestion | choice), `request` (ChatRequest.to_log()), `reply` (ChatResult.to_log()) or
                 `error` (one line).
- `guard`        `step`, `outcome` (ok | parse | schema | bounds | veto), `error`, `attempt`.
- `action`       `step`, `command`, `parameters`, `pose_before`, `pose_after`, `collided`, `collision_with`.
- `pose`         a trajectory sample: `pose` [x, y, yaw]. Path length and final pose come from these.
- `planner`      planner-specific records (waypoint plans and verdicts, FSM tick statistics, suggestions).
- `end`          `outcome` (completed | failed | aborted), `reason`.
"""

from __future__ import annotations

import json
import math
import os
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from llmnav.chat import Image
from llmnav.errors import BadInputError

RUN_FILE = "run.jsonl"
SUMMARY_FILE = "summary.json"
IMAGES_DIR = "images"


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


def write_json_atomic(path: Path, data: dict[str, Any]) -> None:
    """Write JSON via a temporary file and rename, so readers never see half a file."""
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(_clean(data), default=_json_default, indent=2, allow_nan=False) + "\n")
    os.replace(tmp, path)


class RunLog:
    """Append-only writer of one run folder."""

    def __init__(self, run_dir: Path, config: dict[str, Any]) -> None:
        self.run_dir = Path(run_dir)
        if (self.run_dir / RUN_FILE).exists():  # never overwrite a run: nothing already written is lost
            raise BadInputError(f"{self.run_dir} already holds a run ({RUN_FILE}); choose another --out or remove it")
        # The log is born under a temporary name and renamed once its first line is written: a process
        # killed in between leaves no run.jsonl without its configuration (readers would reject it).
        partial = self.run_dir / (RUN_FILE + ".tmp")
        try:
            (self.run_dir / IMAGES_DIR).mkdir(parents=True, exist_ok=True)
            # A lone surrogate (a model answer may carry "\ud800" escapes) cannot be UTF-8: written as the
            # same JSON escape it came from, the line stays valid JSON instead of the write raising.
            self._file = open(partial, "w", encoding="utf-8", errors="backslashreplace")  # noqa: SIM115
        except OSError as err:
            raise BadInputError(f"cannot write run folder {self.run_dir}: {err.strerror or err}") from None
        self._t0 = time.perf_counter()
        self._images: set[str] = set()
        self._lock = threading.Lock()  # a model worker thread may log while the control loop does
        self.sim_time: float | None = None
        self._write({"type": "config", **config})
        os.replace(partial, self.run_dir / RUN_FILE)

    def _write(self, record: dict[str, Any]) -> None:
        line = dumps(record) + "\n"
        with self._lock:
            if self._file.closed:  # a model call abandoned at the end of an episode returned late
                return
            self._file.write(line)
            self._file.flush()  # survives SIGKILL: the line is in the kernel's page cache

    def event(self, type_: str, **fields: Any) -> None:
        """Append one event (flushed at once)."""
        record: dict[str, Any] = {"type": type_, "t_wall": round(time.perf_counter() - self._t0, 4)}
        if self.sim_time is not None and "t_sim" not in fields:
            record["t_sim"] = round(self.sim_time, 4)
        record.update(fields)
        self._write(record)

    def image(self, image: Image) -> str:
        """Store an image once beside the log; returns its hash."""
        digest = image.sha256
        if digest not in self._images:
            path = self.run_dir / IMAGES_DIR / f"{digest}.jpg"
            if not path.exists():
                tmp = path.with_suffix(".tmp")
                tmp.write_bytes(image.jpeg_bytes)
                os.replace(tmp, path)
            self._images.add(digest)
        return digest

    def write_summary(self, summary: dict[str, Any]) -> Path:
        """Write `summary.json` atomically."""
        path = self.run_dir / SUMMARY_FILE
        write_json_atomic(path, summary)
        return path

    def close(self) -> None:
        """Close the log file."""
        if not self._file.closed:
            self._file.close()

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
        """The trajectory: every logged `pose` sample, in order."""
        return [e["pose"] for e in self.events if e.get("type") == "pose" and "pose" in e]


def read_run(run_dir: Path) -> RunRecord:
    """Read a run folder (complete or cut short); raise BadInputError if it is no run folder."""
    path = Path(run_dir) / RUN_FILE
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError:
        raise BadInputError(f"{run_dir}: not a run folder (no {RUN_FILE})") from None
    lines = text.split("\n")
    records: list[dict[str, Any]] = []
    torn = 0
    for number, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        try:
            record = json.loads(line)
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
    summary = None
    summary_path = Path(run_dir) / SUMMARY_FILE
    if summary_path.exists():
        try:
            summary = json.loads(summary_path.read_text(encoding="utf-8"))
        except (json.JSONDecodeError, OSError):
            summary = None
    return RunRecord(Path(run_dir), records[0], records[1:], summary, torn)
