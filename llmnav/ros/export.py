"""A run folder as an MCAP file of ROS 2 messages, for Foxglove, `ros2 bag play` and rosbags.

Topics (log time = the event's sim time; the run's configuration is the MCAP metadata `llmnav.config`):

| topic | type | from |
|---|---|---|
| `/odom` | nav_msgs/Odometry | `odom` of observations and recorded samples (odometry, drifts) |
| `/ground_truth/pose` | geometry_msgs/PoseStamped | the `pose` trajectory samples (the simulator's truth) |
| `/tf` | tf2_msgs/TFMessage | map → odom → base_link wherever both poses are known |
| `/scan` | sensor_msgs/LaserScan | recorded samples (`drive --record-hz`) |
| `/map` | nav_msgs/OccupancyGrid | the recorded `map` event (true occupancy, 100 = occupied) |
| `/camera/image/compressed` | sensor_msgs/CompressedImage | the JPEG an observation names in `images/` |
| `/cmd_vel` | geometry_msgs/Twist | recorded samples' command; the FSM's published `cmd` |
| `/plan` | nav_msgs/Path | planner records carrying waypoints (valid waypoint attempts too) |
| `/llmnav/...` | JSON (`jsonschema`) | model calls (no prompt), guard verdicts, actions, vetoes, planner records, end |

rosbags (and `ros2 bag play`) read ROS 2 encodings only; `ros_only` writes the `/llmnav/...` topics as
std_msgs/String holding the same JSON text.

Messages are serialised by rosbags (CDR) into an MCAP container written by the `mcap` library.
"""

from __future__ import annotations

import base64
import io
import json
import math
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from llmnav import __version__
from llmnav.core.geometry import logged_pose
from llmnav.core.safefiles import IMAGE_LIMIT, UnsafeFileError, image_kind, read_bytes, write_bytes
from llmnav.errors import BadInputError
from llmnav.ros.messages import JSON_TOPICS, TYPES, RosMessages, json_schema, missing_dependency
from llmnav.ros.record import unpack_occupancy
from llmnav.runs.runlog import IMAGES_DIR, RUN_FILE, SUPERSEDED_FILE, RunRecord, dumps, read_run

ROS_TOPICS: dict[str, str] = {  # topic -> ROS 2 type (the key into messages.TYPES)
    "/odom": TYPES["odometry"],
    "/ground_truth/pose": TYPES["pose"],
    "/tf": TYPES["tf"],
    "/scan": TYPES["scan"],
    "/map": TYPES["map"],
    "/camera/image/compressed": TYPES["image"],
    "/cmd_vel": TYPES["twist"],
    "/plan": TYPES["path"],
}
STRING_TYPE = "std_msgs/msg/String"  # JSON topics with --ros-only
MAX_MAP_CELLS = 25_000_000  # a recorded map larger than this is damage, not a world


@dataclass
class ExportResult:
    """What an export wrote: message counts per topic and what the run lacked."""

    path: Path
    counts: Counter[str] = field(default_factory=Counter)
    lacks: list[str] = field(default_factory=list)
    skipped: int = 0  # events whose numbers were damaged (non-finite, wrong shape)


def _number(value: Any) -> float | None:
    if isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value):
        return float(value)
    return None


def _pair(value: Any) -> tuple[float, float] | None:
    if isinstance(value, (list, tuple)) and len(value) == 2:
        a, b = _number(value[0]), _number(value[1])
        if a is not None and b is not None:
            return (a, b)
    return None


def _points(value: Any) -> list[tuple[float, float]] | None:
    if not isinstance(value, list) or not value:
        return None
    points = [_pair(p) for p in value]
    return None if any(p is None for p in points) else [p for p in points if p is not None]


def plan_points(event: dict[str, Any]) -> list[tuple[float, float]] | None:
    """The (x, y) waypoints a planner record plans, or None (a rejected waypoint attempt plans nothing)."""
    if event.get("type") != "planner":
        return None
    if "waypoints" in event:
        return _points(event["waypoints"])
    if event.get("kind") == "waypoint_attempt" and event.get("valid") is True:
        return _points(event.get("points"))
    return None


def _json_record(event: dict[str, Any]) -> dict[str, Any]:
    """An event as a JSON message: the prompt is left out of model calls (it is in run.jsonl)."""
    return {k: v for k, v in event.items() if k not in ("type", "request")}


class _Writer:
    """An MCAP writer that registers each topic's schema and channel on its first message."""

    def __init__(self, stream: io.BytesIO, messages: RosMessages, *, ros_only: bool) -> None:
        # deferred: mcap is the optional 'ros' extra
        from mcap.writer import CompressionType, Writer

        self._writer = Writer(stream, compression=CompressionType.ZSTD)
        self._writer.start(profile="ros2", library=f"llmnav {__version__}")
        self._messages = messages
        self._channels: dict[str, int] = {}
        self._ros_only = ros_only  # JSON topics as std_msgs/String: files rosbags and `ros2 bag play` open
        self.counts: Counter[str] = Counter()

    def _channel(self, topic: str) -> int:
        if topic not in self._channels:
            if topic in ROS_TOPICS or self._ros_only:
                msgtype = ROS_TOPICS.get(topic, STRING_TYPE)
                schema = self._writer.register_schema(
                    name=msgtype, encoding="ros2msg", data=self._messages.definition(msgtype).encode()
                )
                self._channels[topic] = self._writer.register_channel(topic, "cdr", schema)
            else:
                title, properties = JSON_TOPICS[topic]
                data = json.dumps(json_schema(title, properties)).encode()
                schema = self._writer.register_schema(name=title, encoding="jsonschema", data=data)
                self._channels[topic] = self._writer.register_channel(topic, "json", schema)
        return self._channels[topic]

    def ros(self, topic: str, t_sim: float, message: Any) -> None:
        self._add(topic, t_sim, self._messages.serialize(message))

    def json(self, topic: str, t_sim: float, record: dict[str, Any]) -> None:
        text = dumps(record)
        if self._ros_only:
            self.ros(topic, t_sim, self._messages.string(text))
        else:
            self._add(topic, t_sim, text.encode())

    def _add(self, topic: str, t_sim: float, data: bytes) -> None:
        channel = self._channel(topic)
        stamp = round(t_sim * 1e9)  # [ns]
        self._writer.add_message(channel, log_time=stamp, data=data, publish_time=stamp, sequence=self.counts[topic])
        self.counts[topic] += 1

    def metadata(self, name: str, data: dict[str, str]) -> None:
        self._writer.add_metadata(name, data)

    def finish(self) -> None:
        self._writer.finish()


class Sink(Protocol):
    """Where translated messages go: an MCAP file, or a live Foxglove server."""

    def ros(self, topic: str, t_sim: float, message: Any) -> None:
        """One ROS 2 message (a rosbags message object) at sim time `t_sim` [s]."""

    def json(self, topic: str, t_sim: float, record: dict[str, Any]) -> None:
        """One JSON message."""


class Translator:
    """Run-log events to topic messages, one event at a time (a live view feeds it as the run logs)."""

    def __init__(self, run_dir: Path, messages: RosMessages) -> None:
        self.run_dir = run_dir
        self.messages = messages
        self.t_sim = 0.0  # [s] the latest sim time seen: events without one (none normally) take it
        self.true_pose: list[float] | None = None
        self.skipped = 0  # events whose numbers were damaged

    def feed(self, event: dict[str, Any], out: Sink) -> None:
        """Send one event's messages to `out`."""
        kind = event.get("type")
        stamp = _number(event.get("t_sim"))
        if stamp is not None and stamp >= 0.0:
            self.t_sim = stamp
        t_sim = self.t_sim
        if kind == "pose":
            pose = logged_pose(event.get("pose"))
            if pose is None:
                self.skipped += 1
                return
            self.true_pose = pose
            out.ros("/ground_truth/pose", t_sim, self.messages.pose_stamped(t_sim, pose))
        elif kind in ("observation", "sample"):
            odom, pose = logged_pose(event.get("odom")), logged_pose(event.get("pose"))
            self.true_pose = pose or self.true_pose
            velocity = _pair(event.get("velocity"))
            if odom is not None and len(odom) == 3:
                out.ros("/odom", t_sim, self.messages.odometry(t_sim, odom, velocity))
                if self.true_pose is not None and len(self.true_pose) == 3:
                    out.ros("/tf", t_sim, self.messages.tf(t_sim, self.true_pose, odom))
            elif "odom" in event:
                self.skipped += 1
            if kind == "observation":
                _export_image(self.run_dir, event.get("image"), t_sim, out, self.messages)
            else:
                self.skipped += _export_sample(event, t_sim, out, self.messages)
        elif kind == "map":
            self.skipped += _export_map(event, t_sim, out, self.messages)
        elif kind == "planner":
            out.json("/llmnav/planner", t_sim, _json_record(event))
            points = plan_points(event)
            if points is not None:
                out.ros("/plan", t_sim, self.messages.path(t_sim, points))
            fused = _pair(event.get("fused")) if event.get("kind") == "cmd" else None
            if fused is not None:
                out.ros("/cmd_vel", t_sim, self.messages.twist(*fused))
        elif kind == "llm_call":
            out.json("/llmnav/llm_call", t_sim, _json_record(event))
        elif kind == "guard":
            out.json("/llmnav/guard", t_sim, _json_record(event))
        elif kind == "action":
            out.json("/llmnav/action", t_sim, _json_record(event))
            if event.get("vetoed"):
                out.json("/llmnav/veto", t_sim, _json_record(event))
        elif kind == "end":
            out.json("/llmnav/end", t_sim, _json_record(event))


def _export_sample(event: dict[str, Any], t_sim: float, out: Sink, messages: RosMessages) -> int:
    """A recorded sample's scan and velocity command; 1 when its scan is damaged."""
    cmd = _pair(event.get("cmd_vel"))
    if cmd is not None:
        out.ros("/cmd_vel", t_sim, messages.twist(*cmd))
    scan = event.get("scan")
    if not isinstance(scan, dict):
        return 0
    numbers = [_number(scan.get(k)) for k in ("angle_min", "angle_increment", "range_min", "range_max")]
    ranges = _ranges(scan.get("ranges_f32"))
    if any(n is None for n in numbers) or ranges is None:
        return 1
    out.ros("/scan", t_sim, messages.scan(t_sim, {**scan, "ranges": ranges}))
    return 0


def _ranges(packed: Any) -> np.ndarray | None:
    """A sample's ranges [m] (float32; +inf = no return), or None when damaged (NaN, negative, bad base64)."""
    if not isinstance(packed, str) or not packed:
        return None
    try:
        raw = base64.b64decode(packed, validate=True)
    except ValueError:
        return None
    if len(raw) % 4:
        return None
    ranges = np.frombuffer(raw, dtype="<f4")
    if not len(ranges) or np.isnan(ranges).any() or (ranges < 0).any():
        return None
    return ranges


def _export_map(event: dict[str, Any], t_sim: float, out: Sink, messages: RosMessages) -> int:
    """The recorded occupancy grid; 1 when it is damaged."""
    rows, cols = event.get("rows"), event.get("cols")
    origin, resolution = _pair(event.get("origin")), _number(event.get("resolution_m"))
    packed = event.get("occupied")
    if (
        not isinstance(rows, int)
        or not isinstance(cols, int)
        or not 0 < rows * cols <= MAX_MAP_CELLS
        or origin is None
        or resolution is None
        or resolution <= 0
        or not isinstance(packed, str)
    ):
        return 1
    try:
        occupied = unpack_occupancy(packed, rows, cols)
    except ValueError:  # bad base64, or fewer bits than cells
        return 1
    grid = {"origin": origin, "resolution": resolution}
    out.ros("/map", t_sim, messages.occupancy_grid(t_sim, grid, occupied))
    return 0


def _export_image(run_dir: Path, digest: Any, t_sim: float, out: Sink, messages: RosMessages) -> None:
    """The observation's stored JPEG, if the run kept it (a hash only names a file of hex digits)."""
    if not isinstance(digest, str) or not digest or not all(c in "0123456789abcdef" for c in digest):
        return
    try:
        data = read_bytes(run_dir / IMAGES_DIR / f"{digest}.jpg", limit=IMAGE_LIMIT, root=run_dir)
    except (OSError, UnsafeFileError):
        return
    if image_kind(data) == "jpeg":
        out.ros("/camera/image/compressed", t_sim, messages.compressed_image(t_sim, data))


def _lacks(record: RunRecord, counts: Counter[str]) -> list[str]:
    """What the run did not record, as short phrases for one line on stderr."""
    lacks: list[str] = []
    if not record.of_type("sample"):
        lacks.append("no /scan (drive with --record-hz HZ to record scans)")
        if counts["/odom"] == 0:
            lacks.append("no /odom or /tf (the planner made no observations)")
        else:
            lacks.append("/odom and /tf only at the planner's observations")
    if not record.of_type("map"):
        lacks.append("no /map (recorded with --record-hz)")
    if counts["/camera/image/compressed"] == 0:
        lacks.append("no camera images")
    if counts["/cmd_vel"] == 0:
        lacks.append("no /cmd_vel")
    if counts["/plan"] == 0:
        lacks.append("no /plan (the planner logged no waypoints)")
    return lacks


def export_mcap(run_dir: Path, out_path: Path, *, ros_only: bool = False) -> ExportResult:
    """Write a run folder (complete or cut short) as an MCAP file; BadInputError on a bad folder or target.

    The decisions are JSON messages with a JSON Schema (Foxglove shows their fields); `ros_only` writes
    them as std_msgs/String holding the same JSON, for readers that take ROS 2 encodings only (rosbags).
    """
    hint = missing_dependency()
    if hint is not None:
        raise BadInputError(hint)
    out_path = Path(out_path)
    if out_path.exists() or out_path.is_symlink():
        raise BadInputError(f"{out_path} already exists; choose another file (nothing is overwritten)")
    if not out_path.parent.is_dir():
        raise BadInputError(f"{out_path.parent}: no such folder")
    record = read_run(Path(run_dir))
    messages = RosMessages()
    stream = io.BytesIO()
    writer = _Writer(stream, messages, ros_only=ros_only)
    writer.metadata("llmnav.config", {"json": dumps(record.config)})
    translator = Translator(record.run_dir, messages)
    for event in record.events:
        translator.feed(event, writer)
    writer.finish()
    try:
        write_bytes(out_path, stream.getvalue())
    except OSError as err:
        raise BadInputError(f"cannot write {out_path}: {err.strerror or err}") from None
    return ExportResult(out_path, writer.counts, _lacks(record, writer.counts), translator.skipped)


def sweep_runs(folder: Path) -> list[Path]:
    """The run folders directly inside a sweep folder (an ablation's), minus those marked superseded."""
    try:
        children = sorted(p for p in Path(folder).iterdir() if p.is_dir() and not p.is_symlink())
    except OSError as err:
        raise BadInputError(f"cannot read {folder}: {err.strerror or err}") from None
    return [p for p in children if (p / RUN_FILE).is_file() and not (p / SUPERSEDED_FILE).exists()]


def export_sweep(folder: Path, out_dir: Path, *, ros_only: bool = False) -> list[ExportResult]:
    """Each run of a sweep as OUT_DIR/<run folder name>.mcap; OUT_DIR is created and must hold no such file."""
    runs = sweep_runs(folder)
    if not runs:
        raise BadInputError(f"{folder}: neither a run folder nor a folder of runs")
    out_dir = Path(out_dir)
    targets = [out_dir / f"{run.name}.mcap" for run in runs]
    clashes = [t.name for t in targets if t.exists() or t.is_symlink()]
    if clashes:
        raise BadInputError(f"{out_dir}: already holds {clashes[0]}; choose another folder (nothing is overwritten)")
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise BadInputError(f"cannot create {out_dir}: {err.strerror or err}") from None
    return [export_mcap(run, target, ros_only=ros_only) for run, target in zip(runs, targets, strict=True)]
