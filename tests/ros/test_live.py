"""`drive --foxglove`: a real WebSocket client (websockets) subscribes to /scan and /odom during a drive.

The client speaks Foxglove's WebSocket protocol itself (subprotocol `foxglove.sdk.v1`: advertise, subscribe,
binary message frames) and decodes each payload with mcap-ros2-support from the schema text the server advertised.
"""

from __future__ import annotations

import json
import math
import os
import socket
import struct
import threading
import time
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from mcap.records import Schema
from mcap_ros2.decoder import DecoderFactory
from websockets.sync.client import connect

from llmnav.planners.base import drive_options
from llmnav.runs.runner import EpisodeSpec, run_episode

SMALL = str(Path(__file__).parents[1] / "runner" / "small_room.yaml")
WANTED = {"/scan": 3, "/odom": 3}  # messages of each topic the client waits for


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def _connect(port: int, deadline: float) -> Any:
    while True:
        try:
            return connect(f"ws://127.0.0.1:{port}", subprotocols=["foxglove.sdk.v1"], open_timeout=2)
        except OSError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.05)


def test_a_client_receives_and_decodes_scan_and_odom_while_it_drives(
    tmp_path: Path, listening: Callable[[int], list[tuple[str, int]]]
) -> None:
    port = _free_port()
    spec = EpisodeSpec(
        scenario=SMALL,
        task_id="T1",
        options=drive_options(planner="oracle", realtime=True),  # paced: the drive lasts ~10 s of wall time
        out_dir=tmp_path / "run",
        plots=False,
        record_hz=4.0,
        foxglove_port=port,
    )
    summary: dict[str, Any] = {}
    driver = threading.Thread(target=lambda: summary.update(run_episode(spec)), daemon=True)
    driver.start()
    deadline = time.monotonic() + 60.0
    decoded: dict[str, list[Any]] = defaultdict(list)
    with _connect(port, deadline) as ws:
        assert ("127.0.0.1", port) in listening(os.getpid())
        assert all(host == "127.0.0.1" for host, p in listening(os.getpid()) if p == port)
        channels: dict[int, dict[str, Any]] = {}
        subscriptions: dict[int, Any] = {}  # subscription id -> (topic, decoder)
        factory = DecoderFactory()

        def subscribe(channel: dict[str, Any]) -> None:
            schema = Schema(
                id=channel["id"], name=channel["schemaName"], encoding="ros2msg", data=channel["schema"].encode()
            )
            sub = len(subscriptions) + 1
            subscriptions[sub] = (channel["topic"], factory.decoder_for("cdr", schema))
            ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": sub, "channelId": channel["id"]}]}))

        while any(len(decoded[t]) < n for t, n in WANTED.items()):
            assert time.monotonic() < deadline, {t: len(v) for t, v in decoded.items()}
            frame = ws.recv(timeout=max(0.1, deadline - time.monotonic()))
            if isinstance(frame, str):
                message = json.loads(frame)
                if message.get("op") == "status" and "Unknown channel" in message.get("message", ""):
                    # the SDK may not know a channel it has just advertised: ask again a moment later
                    time.sleep(0.05)
                    channel = channels[int(message["message"].rsplit(" ", 1)[-1])]
                    subscribe(channel)
                if message.get("op") != "advertise":
                    continue
                for channel in message["channels"]:
                    channels[channel["id"]] = channel
                    if channel["topic"] in WANTED:
                        assert (channel["encoding"], channel["schemaEncoding"]) == ("cdr", "ros2msg")
                        subscribe(channel)
            else:
                opcode, sub, log_time = struct.unpack_from("<BIQ", frame)
                assert opcode == 1  # message data
                topic, decoder = subscriptions[sub]
                decoded[topic].append((log_time, decoder(frame[13:])))
    driver.join(timeout=60)
    assert summary["success"] and summary["collisions"] == 0
    assert {c["topic"]: c["schemaName"] for c in channels.values() if c["topic"] in WANTED} == {
        "/scan": "sensor_msgs/msg/LaserScan",
        "/odom": "nav_msgs/msg/Odometry",
    }
    for log_time, scan in decoded["/scan"]:
        assert len(scan.ranges) == 360 and scan.range_max == 10.0
        finite = [r for r in scan.ranges if math.isfinite(r)]
        assert finite and all(scan.range_min <= r <= scan.range_max for r in finite)  # inside an 8 x 6 m room
        stamp = scan.header.stamp.sec + scan.header.stamp.nanosec * 1e-9
        assert math.isclose(stamp, log_time * 1e-9, abs_tol=1e-6)
    for _, odom in decoded["/odom"]:
        q = odom.pose.pose.orientation
        assert math.isclose(q.x**2 + q.y**2 + q.z**2 + q.w**2, 1.0, abs_tol=1e-9)
        position = odom.pose.pose.position
        assert 0.0 < position.x < 8.0 and 0.0 < position.y < 6.0 and odom.child_frame_id == "base_link"


def test_a_port_in_use_is_one_line(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from llmnav.cli import app

    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        result = CliRunner().invoke(
            app,
            ["drive", "--planner", "oracle", "--scenario", SMALL, "--task-id", "T1", "--quiet"]
            + ["--foxglove", str(port), "--out", str(tmp_path / "run")],
        )
    assert result.exit_code == 2 and "cannot listen" in result.stderr, result.output
    assert not (tmp_path / "run" / "run.jsonl").exists()  # refused before the run began
    assert len([line for line in result.stderr.splitlines() if "error" in line]) == 1


@pytest.mark.parametrize("port", ["0", "70000", "x"])
def test_a_bad_port_is_refused(tmp_path: Path, port: str) -> None:
    from typer.testing import CliRunner

    from llmnav.cli import app

    result = CliRunner().invoke(
        app, ["drive", "--planner", "oracle", "--task-id", "T1", "--foxglove", port, "--out", str(tmp_path / "r")]
    )
    assert result.exit_code == 2 and "--foxglove" in result.stderr
    assert not (tmp_path / "r").exists()
