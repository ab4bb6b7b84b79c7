"""`llmnav export --mcap`: real drives exported, read back with readers other than the writer's.

The file is written with rosbags' CDR serialiser in an `mcap` container; it is read back with Foxglove's
`mcap-ros2-support` decoder (its own `.msg` parser and CDR reader) and, for `--ros-only`, with rosbags'
AnyReader. Every expected number comes from run.jsonl (or the scenario), never from the exporter.
"""

from __future__ import annotations

import base64
import json
import math
import shutil
from collections import Counter, defaultdict
from pathlib import Path
from typing import Any

import jsonschema
import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from typer.testing import CliRunner

from llmnav.cli import app
from llmnav.planners.base import drive_options
from llmnav.runs.runner import EpisodeSpec, run_episode
from llmnav.world.scenario import load_scenario

runner = CliRunner()
SMALL = Path(__file__).parents[1] / "runner" / "small_room.yaml"
RATE_HZ = 4.0  # [Hz] recording rate of the recorded runs


def _events(run_dir: Path) -> list[dict[str, Any]]:
    return [json.loads(line) for line in (run_dir / "run.jsonl").read_text().splitlines() if line.strip()]


def _drive(out: Path, planner: str, *, scenario: str = "factory", record: bool, **options: Any) -> Path:
    spec = EpisodeSpec(
        scenario=scenario,
        task_id="T1",
        options=drive_options(planner=planner, **options),
        backend="policy:first" if planner == "stepwise" else "local",
        out_dir=out,
        plots=False,
        record_hz=RATE_HZ if record else None,
    )
    run_episode(spec)
    return out


def _export(run_dir: Path, out: Path, *extra: str) -> Any:
    result = runner.invoke(app, ["export", str(run_dir), "--mcap", str(out), *extra])
    assert result.exit_code == 0, result.output
    return result


def _read(path: Path) -> dict[str, list[tuple[str, str, Any, int]]]:
    """topic -> [(schema name, schema encoding, decoded message, log time ns)] via mcap + mcap-ros2-support."""
    by_topic: dict[str, list[tuple[str, str, Any, int]]] = defaultdict(list)
    with path.open("rb") as handle:
        reader = make_reader(handle, decoder_factories=[DecoderFactory()])
        for schema, channel, message, decoded in _iter(reader):
            by_topic[channel.topic].append((schema.name, schema.encoding, decoded, message.log_time))
    return by_topic


def _iter(reader: Any) -> Any:
    """Decoded messages; JSON channels decoded here and checked against their channel's JSON schema."""
    ros2 = DecoderFactory()
    for schema, channel, message in reader.iter_messages():
        if channel.message_encoding == "json":
            assert schema.encoding == "jsonschema"
            value = json.loads(message.data)
            jsonschema.validate(value, json.loads(schema.data))
            yield schema, channel, message, value
        else:
            assert (channel.message_encoding, schema.encoding) == ("cdr", "ros2msg")
            decoder = ros2.decoder_for(channel.message_encoding, schema)
            assert decoder is not None
            yield schema, channel, message, decoder(message.data)


def _yaw(q: Any) -> float:
    assert math.isclose(q.x**2 + q.y**2 + q.z**2 + q.w**2, 1.0, abs_tol=1e-9)
    assert q.x == 0.0 and q.y == 0.0
    return 2.0 * math.atan2(q.z, q.w)


def _same_angle(a: float, b: float) -> bool:
    return abs(math.remainder(a - b, 2 * math.pi)) < 1e-6


def _stamp(header: Any) -> float:
    return header.stamp.sec + header.stamp.nanosec * 1e-9


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, list]]:
    """An oracle drive in the factory, recorded at 4 Hz, exported."""
    folder = tmp_path_factory.mktemp("recorded")
    run_dir = _drive(folder / "run", "oracle", record=True)
    _export(run_dir, folder / "run.mcap")
    return run_dir, _read(folder / "run.mcap")


@pytest.fixture(scope="module")
def stepwise(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A stepwise drive (null policy: camera images, model calls, guard verdicts), not recorded."""
    folder = tmp_path_factory.mktemp("stepwise")
    return _drive(folder / "run", "stepwise", record=False, max_iterations=5)


def test_each_topic_has_its_standard_type_and_one_message_per_logged_source(recorded: tuple) -> None:
    run_dir, topics = recorded
    events = _events(run_dir)
    kinds = Counter(e["type"] for e in events)
    samples = [e for e in events if e["type"] == "sample"]
    with_odom = [e for e in events if e["type"] in ("sample", "observation") and "odom" in e]
    planned = [e for e in events if e["type"] == "planner" and "waypoints" in e]
    expected = {
        "/ground_truth/pose": ("geometry_msgs/msg/PoseStamped", kinds["pose"]),
        "/odom": ("nav_msgs/msg/Odometry", len(with_odom)),
        "/tf": ("tf2_msgs/msg/TFMessage", len(with_odom)),
        "/scan": ("sensor_msgs/msg/LaserScan", len(samples)),
        "/cmd_vel": ("geometry_msgs/msg/Twist", len(samples)),
        "/map": ("nav_msgs/msg/OccupancyGrid", 1),
        "/plan": ("nav_msgs/msg/Path", len(planned)),
        "/llmnav/action": ("llmnav.Action", kinds["action"]),
        "/llmnav/end": ("llmnav.End", 1),
    }
    for topic, (msgtype, count) in expected.items():
        assert count > 0, topic
        assert {m[0] for m in topics[topic]} == {msgtype}, topic
        assert len(topics[topic]) == count, topic
    duration = max(e.get("t_sim", 0.0) for e in events)  # [s]
    # recorded at the stated rate, bounded by the 0.25 s pose period: between 2 and 4 samples per second
    assert 2.0 * duration <= len(samples) <= RATE_HZ * duration + 1


def test_odometry_tf_and_true_pose_carry_the_logged_poses(recorded: tuple) -> None:
    run_dir, topics = recorded
    events = _events(run_dir)
    samples = [e for e in events if e["type"] == "sample"]
    for event, (_, _, odom, log_time) in zip(samples, topics["/odom"], strict=True):
        assert math.isclose(_stamp(odom.header), event["t_sim"], abs_tol=1e-6)
        assert log_time == round(event["t_sim"] * 1e9)
        assert (odom.header.frame_id, odom.child_frame_id) == ("odom", "base_link")
        position = odom.pose.pose.position
        assert (position.x, position.y) == (event["odom"][0], event["odom"][1])
        assert _same_angle(_yaw(odom.pose.pose.orientation), event["odom"][2])
        assert math.isclose(odom.twist.twist.linear.x, event["velocity"][0], abs_tol=1e-9)
        assert math.isclose(odom.twist.twist.angular.z, event["velocity"][1], abs_tol=1e-9)
    for event, (_, _, tf, _) in zip(samples, topics["/tf"], strict=True):
        first, second = tf.transforms
        assert (first.header.frame_id, first.child_frame_id) == ("map", "odom")
        assert (second.header.frame_id, second.child_frame_id) == ("odom", "base_link")
        # map -> base_link by composing the two transforms must be the true pose
        a_yaw, b_yaw = _yaw(first.transform.rotation), _yaw(second.transform.rotation)
        bx, by = second.transform.translation.x, second.transform.translation.y
        x = first.transform.translation.x + math.cos(a_yaw) * bx - math.sin(a_yaw) * by
        y = first.transform.translation.y + math.sin(a_yaw) * bx + math.cos(a_yaw) * by
        assert math.isclose(x, event["pose"][0], abs_tol=1e-6) and math.isclose(y, event["pose"][1], abs_tol=1e-6)
        assert _same_angle(a_yaw + b_yaw, event["pose"][2])
    poses = [e for e in events if e["type"] == "pose"]
    for event, (_, _, msg, _) in zip(poses, topics["/ground_truth/pose"], strict=True):
        assert msg.header.frame_id == "map"
        assert (msg.pose.position.x, msg.pose.position.y) == (event["pose"][0], event["pose"][1])
        assert _same_angle(_yaw(msg.pose.orientation), event["pose"][2])


def test_scans_cmd_vel_map_and_plan_hold_the_logged_values(recorded: tuple) -> None:
    run_dir, topics = recorded
    events = _events(run_dir)
    samples = [e for e in events if e["type"] == "sample"]
    for event, (_, _, scan, _) in zip(samples, topics["/scan"], strict=True):
        logged = [float(r) for r in np.frombuffer(base64.b64decode(event["scan"]["ranges_f32"]), dtype="<f4")]
        assert len(scan.ranges) == len(logged) == 360  # the factory LiDAR: 360 rays
        assert math.isclose(scan.angle_min, -math.pi, abs_tol=1e-6)
        assert math.isclose(scan.angle_increment, 2 * math.pi / 360, rel_tol=1e-6)
        assert scan.range_min <= scan.range_max == 10.0
        for got, want in zip(scan.ranges, logged, strict=True):
            if want == math.inf:
                assert got == math.inf
            else:
                assert scan.range_min <= got <= scan.range_max and math.isclose(got, want, abs_tol=1e-5)
        assert any(math.isfinite(r) for r in scan.ranges)  # walls within 10 m somewhere around
    for event, (_, _, twist, _) in zip(samples, topics["/cmd_vel"], strict=True):
        assert (twist.linear.x, twist.angular.z) == tuple(event["cmd_vel"])
    assert any(twist.linear.x > 0.1 for _, _, twist, _ in topics["/cmd_vel"])  # it drove

    ((_, _, grid, _),) = topics["/map"]
    info = grid.info
    assert len(grid.data) == info.width * info.height and set(grid.data) <= {0, 100}
    assert math.isclose(info.resolution, 0.05, rel_tol=1e-6)  # float32 in the message

    def cell(x: float, y: float) -> int:
        col = int((x - info.origin.position.x) / info.resolution)
        row = int((y - info.origin.position.y) / info.resolution)
        return int(grid.data[row * info.width + col])

    scenario = load_scenario("factory")
    for wall in scenario.walls[:5]:  # a wall's centre is occupied, the start pose is free
        assert cell(wall.center[0], wall.center[1]) == 100, wall.id
    start = next(e for e in events if e["type"] == "pose")["pose"]
    assert cell(start[0], start[1]) == 0

    planned = [e for e in events if e["type"] == "planner" and "waypoints" in e]
    for event, (_, _, path, _) in zip(planned, topics["/plan"], strict=True):
        assert path.header.frame_id == "map"
        points = [(p.pose.position.x, p.pose.position.y) for p in path.poses]
        assert points == [tuple(w) for w in event["waypoints"]]


def test_images_and_decisions_of_a_model_run(stepwise: Path, tmp_path: Path) -> None:
    _export(stepwise, tmp_path / "run.mcap")
    topics = _read(tmp_path / "run.mcap")
    events = _events(stepwise)
    observations = [e for e in events if e["type"] == "observation"]
    assert observations and all(e.get("image") for e in observations)
    images = topics["/camera/image/compressed"]
    assert len(images) == len(observations)
    for event, (name, _, image, _) in zip(observations, images, strict=True):
        assert name == "sensor_msgs/msg/CompressedImage" and image.format == "jpeg"
        assert bytes(image.data) == (stepwise / "images" / f"{event['image']}.jpg").read_bytes()
    assert len(topics["/odom"]) == len(observations)  # no samples: odometry at the observations only
    for topic, kind in (("/llmnav/guard", "guard"), ("/llmnav/llm_call", "llm_call"), ("/llmnav/action", "action")):
        logged = [e for e in events if e["type"] == kind]
        assert logged, kind
        got = [m[2] for m in topics[topic]]
        assert len(got) == len(logged)
        for value, event in zip(got, logged, strict=True):
            assert value["step"] == event["step"] and value["t_sim"] == event["t_sim"]
            assert "request" not in value  # the prompt stays in run.jsonl
        if kind == "guard":
            assert [v["value"] for v in got] == [e["value"] for e in logged]
    assert "/scan" not in topics and "/map" not in topics


def test_export_names_what_the_run_lacks(stepwise: Path, tmp_path: Path) -> None:
    result = _export(stepwise, tmp_path / "run.mcap")
    lines = [line for line in result.stderr.splitlines() if line.startswith("note:")]
    assert len(lines) == 1
    assert "no /scan" in lines[0] and "--record-hz" in lines[0] and "no /map" in lines[0]


def test_a_vetoed_action_is_on_the_veto_topic(stepwise: Path, tmp_path: Path) -> None:
    run_dir = tmp_path / "vetoed"
    shutil.copytree(stepwise, run_dir)
    lines = (run_dir / "run.jsonl").read_text().splitlines()
    index = next(i for i, line in enumerate(lines) if json.loads(line)["type"] == "action")
    action = json.loads(lines[index])
    action.update(vetoed=True, veto={"reason": "obstacle 0.3 m ahead"})
    lines[index] = json.dumps(action)
    (run_dir / "run.jsonl").write_text("\n".join(lines) + "\n")
    _export(run_dir, tmp_path / "run.mcap")
    ((_, _, veto, _),) = _read(tmp_path / "run.mcap")["/llmnav/veto"]
    assert veto["veto"] == {"reason": "obstacle 0.3 m ahead"} and veto["step"] == action["step"]


def test_ros_only_file_opens_in_rosbags(stepwise: Path, tmp_path: Path) -> None:
    from rosbags.highlevel import AnyReader

    _export(stepwise, tmp_path / "run.mcap", "--ros-only")
    events = _events(stepwise)
    counts: Counter[str] = Counter()
    guards = []
    with AnyReader([tmp_path / "run.mcap"]) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        for connection, _, raw in reader.messages():
            message = reader.deserialize(raw, connection.msgtype)
            counts[connection.topic] += 1
            if connection.topic == "/llmnav/guard":
                guards.append(json.loads(message.data))
    assert types["/llmnav/guard"] == "std_msgs/msg/String" and types["/odom"] == "nav_msgs/msg/Odometry"
    assert counts["/ground_truth/pose"] == sum(e["type"] == "pose" for e in events)
    assert [g["value"] for g in guards] == [e["value"] for e in events if e["type"] == "guard"]


def test_recording_leaves_the_run_unchanged(tmp_path: Path) -> None:
    """Extra LiDAR scans with their own noise: the planner's readings and so the trajectory are the same."""
    data = yaml.safe_load(SMALL.read_text())
    data["sensors"] = {"lidar": {"noise_std_m": 0.02}}
    scenario = tmp_path / "noisy.yaml"
    scenario.write_text(yaml.safe_dump(data))
    trajectories = []
    for record in (False, True):
        run_dir = _drive(
            tmp_path / f"run-{record}", "stepwise", scenario=str(scenario), record=record, max_iterations=4
        )
        events = _events(run_dir)
        trajectories.append([e["pose"] for e in events if e["type"] == "pose"])
        observed = [e["lidar_sectors"] for e in events if e["type"] == "observation"]
        trajectories.append(observed)
        assert any(e["type"] == "sample" for e in events) == record
    assert trajectories[0] == trajectories[2] and trajectories[1] == trajectories[3]


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["--mcap", "{tmp}/x.txt"], "ending in .mcap"),
        ([], "--mcap"),
        (["--mcap", "{tmp}/exists.mcap"], "already exists"),
        (["--mcap", "{tmp}/nofolder/x.mcap"], "no such folder"),
    ],
)
def test_bad_export_arguments_are_one_line_and_write_nothing(
    stepwise: Path, tmp_path: Path, args: list[str], words: str
) -> None:
    (tmp_path / "exists.mcap").write_bytes(b"keep me")
    result = runner.invoke(app, ["export", str(stepwise), *[a.format(tmp=tmp_path) for a in args]])
    assert result.exit_code == 2
    assert words in result.stderr and len(result.stderr.strip().splitlines()) == 1
    assert (tmp_path / "exists.mcap").read_bytes() == b"keep me"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["exists.mcap"]


def test_a_folder_without_a_run_is_refused(tmp_path: Path) -> None:
    result = runner.invoke(app, ["export", str(tmp_path), "--mcap", str(tmp_path / "x.mcap")])
    assert result.exit_code == 2 and "neither a run folder nor a folder of runs" in result.stderr
    assert not (tmp_path / "x.mcap").exists()


@pytest.mark.parametrize("rate", ["0", "-1", "nan", "1000"])
def test_a_bad_recording_rate_is_refused_before_driving(tmp_path: Path, rate: str) -> None:
    out = tmp_path / "run"
    result = runner.invoke(
        app, ["drive", "--planner", "oracle", "--task-id", "T1", "--record-hz", rate, "--out", str(out), "--quiet"]
    )
    assert result.exit_code == 2 and "--record-hz" in result.stderr
    assert not out.exists()


def test_a_sweep_exports_one_file_per_run(tmp_path: Path) -> None:
    sweep = tmp_path / "sweep"
    args = ["ablate", "--scenario", "factory", "--tasks", "T1,T2", "--poses", "1", "--planner", "oracle"]
    result = runner.invoke(app, [*args, "--out", str(sweep), "--export", "mcap"])
    assert result.exit_code == 0, result.output
    runs = sorted(p for p in sweep.iterdir() if (p / "run.jsonl").is_file())
    assert len(runs) == 2
    again = runner.invoke(app, ["export", str(sweep), "--mcap", str(tmp_path / "again")])
    assert again.exit_code == 0, again.output
    for folder in (sweep / "mcap", tmp_path / "again"):
        assert sorted(p.name for p in folder.iterdir()) == [f"{run.name}.mcap" for run in runs]
        for run in runs:
            poses = [e for e in _events(run) if e["type"] == "pose"]
            assert len(_read(folder / f"{run.name}.mcap")["/ground_truth/pose"]) == len(poses)
    clash = runner.invoke(app, ["export", str(sweep), "--mcap", str(tmp_path / "again")])
    assert clash.exit_code == 2 and "already holds" in clash.stderr


def test_damaged_numbers_are_skipped_and_counted(recorded: tuple, tmp_path: Path) -> None:
    run_dir, _ = recorded
    copy = tmp_path / "damaged"
    shutil.copytree(run_dir, copy)
    events = _events(copy)
    first_sample = next(i for i, e in enumerate(events) if e["type"] == "sample")
    events[first_sample]["scan"]["ranges_f32"] = "not base64!"
    next(e for e in events if e["type"] == "map")["occupied"] = "AAAA"  # too few bits for the grid
    next(e for e in events if e["type"] == "pose")["pose"] = [1e308, 0.0, 0.0]
    (copy / "run.jsonl").write_text("".join(json.dumps(e) + "\n" for e in events))
    result = _export(copy, tmp_path / "run.mcap")
    assert "3 damaged event(s) skipped" in result.stderr
    topics = _read(tmp_path / "run.mcap")
    assert len(topics["/scan"]) == sum(e["type"] == "sample" for e in events) - 1
    assert "/map" not in topics
    assert len(topics["/ground_truth/pose"]) == sum(e["type"] == "pose" for e in events) - 1


def test_an_image_linked_out_of_the_run_folder_is_not_embedded(stepwise: Path, tmp_path: Path) -> None:
    copy = tmp_path / "linked"
    shutil.copytree(stepwise, copy)
    outside = tmp_path / "secret.jpg"
    outside.write_bytes(b"\xff\xd8\xff not the camera's")
    images = sorted((copy / "images").iterdir())
    images[0].unlink()
    images[0].symlink_to(outside)
    _export(copy, tmp_path / "run.mcap")
    got = [bytes(m[2].data) for m in _read(tmp_path / "run.mcap")["/camera/image/compressed"]]
    observed = [e["image"] for e in _events(copy) if e["type"] == "observation"]
    assert len(got) == len(observed) - observed.count(images[0].stem)
    assert outside.read_bytes() not in got
