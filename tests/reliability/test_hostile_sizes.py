"""Hostile sizes: numbers and nesting no real run holds, grids too large to build, flags without bound.

Each case reproduces a RecursionError, MemoryError, crash or unbounded job of an earlier llmnav: JSON
nested 200,000 deep from a server or a replay file, NaN and 1e308 poses in a log, `replay:/dev/zero`, a
grid of a billion trials (even with --dry-run), `--fps nan`/`inf`, `--fps 100000`, a binary or
self-contradicting grid file, and more --workers than cores. Property: every command ends promptly with
exit 0 or a one-line error (exit 2), no traceback, and nothing is built before the size is checked.
Counted as category "hostile sizes".
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

sys.path.insert(0, str(Path(__file__).parents[1] / "score"))
sys.path.insert(0, str(Path(__file__).parent))
from score_fakes import write_scenario_file  # noqa: E402
from test_hostile_folders import make_run  # noqa: E402

from llmnav import ablate as lib  # noqa: E402
from llmnav.backends.http import HttpOptions, JsonHttpClient  # noqa: E402
from llmnav.cli import app  # noqa: E402
from llmnav.errors import BadInputError, ModelError  # noqa: E402
from llmnav.runs.runlog import RUN_FILE  # noqa: E402

CATEGORY = "hostile sizes"
DEEP = "[" * 200_000


def _cli(*args: str) -> tuple[int, str]:
    result = CliRunner().invoke(app, list(args))
    text = result.output + (result.stderr if result.stderr_bytes is not None else "")
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    assert "Traceback" not in text, text
    return result.exit_code, text


def test_deeply_nested_server_reply_is_a_model_error(server, tally) -> None:
    tally.add(CATEGORY, tried=3)
    server.default = server.reply(200, DEEP)
    client = JsonHttpClient("test", server.url, HttpOptions(max_retries=0))
    with pytest.raises(ModelError, match="not a JSON object"):
        client.get("/v1/models")
    server.default = server.reply(500, '{"error": ' + DEEP)  # the error body is parsed for a reason too
    with pytest.raises(ModelError, match="HTTP 500"):
        client.get("/v1/models")
    client.close()
    server.default = server.reply(200, DEEP)
    code, text = _cli("backends", "--check", f"openai:m@{server.url}/v1")
    assert code != 0 and "RecursionError" not in text, text


def test_non_finite_and_huge_poses_count_as_missing(tmp_path: Path, tally) -> None:
    for bad in ("NaN", "1e308", "-Infinity", '"inf"'):
        tally.add(CATEGORY, tried=2)
        run, _ = make_run(tmp_path / bad.strip('"'))
        text = (run / RUN_FILE).read_text()
        text = text.replace('"pose": [1.0, 0.0, 0.0]', f'"pose": [{bad}, 0.0, 0.0]')
        text = text.replace('"pose_after": [1, 0, 0]', f'"pose_after": [{bad}, 0, 0]')
        (run / RUN_FILE).write_text(text)
        for command in ("view", "score"):
            code, out = _cli(command, str(run))
            assert code == 0, f"{bad} {command}: {out}"


def test_replay_of_a_device_or_deep_file_is_a_one_line_error(tmp_path: Path, tally) -> None:
    from llmnav.backends.replay import load_recording

    tally.add(CATEGORY, tried=3)
    with pytest.raises(BadInputError, match="not a regular file"):
        load_recording(Path("/dev/zero"))
    fifo = tmp_path / "fifo.jsonl"
    os.mkfifo(fifo)
    with pytest.raises(BadInputError, match="not a regular file"):
        load_recording(fifo)
    deep = tmp_path / "deep.jsonl"
    deep.write_text('{"type": "config"}\n' + DEEP + "\n{}\n")
    with pytest.raises(BadInputError, match="line 2: not valid JSON"):
        load_recording(deep)


def _grid(tmp_path: Path, **data: object) -> lib.GridSpec:
    scenario = str(write_scenario_file(tmp_path / "tiny.yaml"))
    return lib.grid_from_mapping({"scenario": scenario, "backend": ["replay:x"], **data}, "test")


def test_a_huge_grid_is_refused_before_it_is_built(tmp_path: Path, tally) -> None:
    tally.add(CATEGORY, tried=4)
    t0 = time.perf_counter()
    with pytest.raises(BadInputError, match="over the limit of 20,000; use --max-episodes"):
        lib.plan(_grid(tmp_path, trials=1_000_000_000), tmp_path / "abl")
    values = {"lidar_sectors": list(range(1, 101)), "history": [str(k) for k in range(100)], "trials": 400_000}
    with pytest.raises(BadInputError, match="over the limit"):
        lib.plan(_grid(tmp_path, **values), tmp_path / "abl")
    assert time.perf_counter() - t0 < 30  # refused from the factor lengths, not after building them
    assert lib.plan(_grid(tmp_path, tasks=["T1"], trials=3), tmp_path / "abl", max_episodes=6).size == 6
    with pytest.raises(BadInputError, match="7 episodes|over the limit of 6"):
        lib.plan(_grid(tmp_path, tasks=["T1"], trials=4), tmp_path / "abl", max_episodes=6)
    scenario = str(tmp_path / "tiny.yaml")
    code, text = _cli("ablate", "--scenario", scenario, "--backend", "replay:x", "--trials", "1000000000", "--dry-run")
    assert code == 2 and "--max-episodes" in text, text


def test_bad_grid_files_are_one_line_errors(tmp_path: Path, tally) -> None:
    tally.add(CATEGORY, tried=3)
    binary = tmp_path / "grid.yaml"
    binary.write_bytes(bytes(range(256)) * 4)
    code, text = _cli("ablate", "--grid", str(binary), "--dry-run")
    assert code == 2 and "not a text file" in text, text
    twice = tmp_path / "twice.yaml"
    twice.write_text("trials: 1\nseed: 3\ntrials: 5\n")
    code, text = _cli("ablate", "--grid", str(twice), "--dry-run")
    assert code == 2 and "'trials' is given twice" in text and "line 3" in text, text
    code, text = _cli("ablate", "--grid", "/dev/zero", "--dry-run")
    assert code == 2 and "not a regular file" in text, text


def test_workers_are_capped_at_the_usable_cores(tmp_path: Path, tally, monkeypatch) -> None:
    tally.add(CATEGORY, tried=1)
    seen: dict[str, int] = {}

    def fake_run(ablation: object, *, workers: int, **_: object) -> object:
        seen["workers"] = workers
        raise BadInputError("stop here")

    monkeypatch.setattr(lib, "run", fake_run)
    scenario = str(write_scenario_file(tmp_path / "tiny.yaml"))
    code, text = _cli("ablate", "--scenario", scenario, "--backend", "replay:x", "--workers", "10000",
                      "--out", str(tmp_path / "abl"))  # fmt: skip
    cores = len(os.sched_getaffinity(0))
    assert seen["workers"] == cores and f"capped at {cores}" in text, text


@pytest.mark.parametrize(
    ("flag", "value"),
    [("--fps", "nan"), ("--fps", "inf"), ("--fps", "100000"), ("--fps", "0"), ("--fps", "0.001"), ("--fps", "0.5"),
     ("--seconds-per-step", "inf"),
     ("--seconds-per-step", "nan"), ("--seconds-per-step", "1e9")],
)  # fmt: skip
def test_video_timing_flags_are_bounded(tmp_path: Path, tally, flag: str, value: str) -> None:
    tally.add(CATEGORY, tried=1)
    run, _ = make_run(tmp_path / "run")
    t0 = time.perf_counter()
    code, text = _cli("view", str(run), "--video", str(tmp_path / "v.gif"), flag, value)
    assert code == 2 and flag in text, text
    assert not (tmp_path / "v.gif").exists() and not (run / "view.html").exists()  # refused before any work
    assert time.perf_counter() - t0 < 60


def test_a_video_of_too_many_frames_is_refused_before_drawing(tmp_path: Path, tally, monkeypatch) -> None:
    from llmnav.view import video
    from llmnav.view.model import build_run_view

    tally.add(CATEGORY, tried=1)
    run, _ = make_run(tmp_path / "run")
    assert video.frame_count(build_run_view(run), 10, 1) == 10  # one decision with one action: 10 frames
    monkeypatch.setattr(video, "MAX_FRAMES", 9)
    monkeypatch.setattr(video, "_frames", lambda *_: pytest.fail("frames drawn before the count was checked"))
    code, text = _cli("view", str(run), "--video", str(tmp_path / "v.gif"))
    assert code == 2 and "10 frames" in text and "limit of 9" in text, text
    assert not (tmp_path / "v.gif").exists()


def test_one_wording_written_two_ways_is_a_duplicate(tmp_path: Path, tally) -> None:
    tally.add(CATEGORY, tried=1)
    with pytest.raises(BadInputError, match="the same value twice"):
        _grid(tmp_path, wording=["paraphrase:1", "paraphrase:01"])
    assert _grid(tmp_path, wording=["bundled", "paraphrase:02"]).wording == ["bundled", "paraphrase:2"]


def _hostile_room(tmp_path: Path, change: str) -> Path:
    """The small test room with one hostile change (written by hand, not by the code under test)."""
    import yaml

    room = yaml.safe_load((Path(__file__).parents[1] / "runner" / "small_room.yaml").read_text())
    if change == "bounds ±1e6 m":
        room["bounds"] = {"x": [-1e6, 1e6], "y": [-1e6, 1e6]}
    elif change == "bounds 1 km wide":
        room["bounds"] = {"x": [0.0, 1000.0], "y": [0.0, 6.0]}
    elif change == "bounds reversed":
        room["bounds"] = {"x": [8.0, 0.0], "y": [0.0, 6.0]}
    elif change == "2,000 objects":
        room["objects"] += [{"id": f"o{i}", "label": "crate", "center": [1.0 + (i % 60) * 0.1, 1.0 + (i // 60) * 0.1],
                             "size": [0.05, 0.05]} for i in range(2000)]  # fmt: skip
    elif change == "6 MB task text":
        room["tasks"][0]["text"] = "go to the red box " * 350_000
    elif change == "20,000-character label":
        room["objects"][0]["label"] = "red box " * 2500
    path = tmp_path / "hostile.yaml"
    path.write_text(yaml.safe_dump(room), encoding="utf-8")
    return path


@pytest.mark.parametrize(
    "change",
    ["bounds ±1e6 m", "bounds 1 km wide", "bounds reversed", "2,000 objects", "6 MB task text",
     "20,000-character label"],  # fmt: skip
)
def test_a_world_too_large_is_refused_at_validation(tmp_path: Path, tally, change: str) -> None:
    """±1e6 m bounds passed validation, then `drive --planner oracle` asked numpy for 1.42 PiB; 2,000 objects
    kept `drive` plotting past 240 s; a 6 MB task text kept `scenarios show` busy past 120 s."""
    tally.add(CATEGORY, tried=1)
    path = _hostile_room(tmp_path, change)
    t0 = time.perf_counter()
    code, text = _cli("scenarios", "show", str(path))
    assert code == 2 and len(set(text.strip().splitlines())) == 1 and "hostile.yaml" in text, text  # out + err
    code, text = _cli("drive", "--planner", "oracle", "--scenario", str(path), "--task-id", "T1",
                      "--out", str(tmp_path / "run"))  # fmt: skip
    assert code == 2 and "hostile.yaml" in text, text
    assert not (tmp_path / "run").exists()
    assert time.perf_counter() - t0 < 60
