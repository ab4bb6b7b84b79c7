"""Inputs that used to crash or mislead: each is one line on stderr with exit 2 before any work, or (a full
disk) one line with a non-zero exit and a log that stays readable.

Non-finite scenario sizes and obstacles, obstacles on the start pose or outside the world, plot paths
that are folders or unknown formats, backend URLs no request could use, a planner that cannot run on the
scenario, and the small ones: an empty --task, --lidar-fov's name, repeated sensors, an --name that is a
path, --dry-run accepting what the real run refuses, an hour of audio, pybullet's build-time banner.
"""

from __future__ import annotations

import json
import os
import resource
import signal
import subprocess
import sys
import wave
from pathlib import Path

import pytest
from typer.testing import CliRunner

from llmnav.cli import app
from llmnav.runs.runlog import read_run

ENTRY = "from llmnav.cli import main; main()"
SMALL_ROOM = str(Path(__file__).parent / "runner" / "small_room.yaml")
DRIVE = ["drive", "--scenario", SMALL_ROOM, "--task-id", "T1"]


def invoke(*args: str, env: dict[str, str] | None = None) -> tuple[int, str]:
    result = CliRunner().invoke(app, list(args), env=env)
    assert result.exception is None or isinstance(result.exception, SystemExit), result.exception
    return result.exit_code, result.output


def one_line_error(code: int, output: str, *needles: str) -> None:
    assert code == 2, output
    assert len(output.strip().splitlines()) == 1 and output.startswith("error:"), output
    for needle in needles:
        assert needle in output, output


# --- 13. NaN, infinity, and obstacles where they cannot be --------------------------------------------


@pytest.mark.parametrize("value", [".nan", ".inf", "-.inf"])
def test_non_finite_scenario_sizes_are_refused_at_load(tmp_path: Path, value: str) -> None:
    path = tmp_path / "s.yaml"
    path.write_text(Path(SMALL_ROOM).read_text().replace("size: [0.6, 0.6]", f"size: [{value}, 0.6]"))
    one_line_error(*invoke("scenarios", "show", str(path)), "objects[0].size", "finite")
    one_line_error(*invoke("drive", "--scenario", str(path), "--task-id", "T1", "--planner", "oracle",
                           "--out", str(tmp_path / "run")))
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("obstacle,needle", [("nan,nan", "finite"), ("1e309,0", "finite"),
                                             ("1.5,3", "start pose"), ("1.7,3.2", "start pose"),
                                             ("1e6,1e6", "outside the world")])
def test_bad_obstacles_are_refused_before_the_run(tmp_path: Path, obstacle: str, needle: str) -> None:
    out = tmp_path / "run"
    one_line_error(*invoke(*DRIVE, "--planner", "oracle", "--obstacle", obstacle, "--out", str(out)), needle)
    assert not out.exists()


# --- 14. a full disk: one line, non-zero, the log readable ----------------------------------------------


def drive_with_file_limit(limit: int, out: Path) -> subprocess.CompletedProcess[str]:
    """`llmnav drive` where no file may grow past `limit` bytes (writes beyond fail like a full disk)."""

    def limit_files() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    return subprocess.run([sys.executable, "-c", ENTRY, *DRIVE, "--planner", "oracle", "--out", str(out),
                           "--quiet"], preexec_fn=limit_files, capture_output=True, text=True, timeout=300)


@pytest.mark.skipif(not hasattr(resource, "RLIMIT_FSIZE"), reason="needs RLIMIT_FSIZE")
def test_disk_full_during_drive(tmp_path: Path) -> None:
    log_full = drive_with_file_limit(3000, tmp_path / "a")  # the log stops after a few events
    assert log_full.returncode == 1 and "Traceback" not in log_full.stderr, log_full.stderr
    assert log_full.stderr.strip().splitlines() == [log_full.stderr.strip()], log_full.stderr
    assert "run.jsonl" in log_full.stderr and "readable" in log_full.stderr
    record = read_run(tmp_path / "a")  # complete lines valid, at most the last one torn
    assert record.torn_lines <= 1 and record.config["planner"] == "oracle"
    plot_full = drive_with_file_limit(20_000, tmp_path / "b")  # log and summary fit, the figure does not
    assert plot_full.returncode == 1 and "Traceback" not in plot_full.stderr, plot_full.stderr
    assert "trajectory.png not written" in plot_full.stderr and len(plot_full.stderr.strip().splitlines()) == 1
    assert json.loads((tmp_path / "b" / "summary.json").read_text())["outcome"] == "completed"


# --- 15. plot paths are checked before the work, and the path reported is the one written -----------------


def test_plot_paths(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    # plan: the format is checked before the model is even created (the backend here does not exist)
    one_line_error(*invoke("plan", "--task", "go to room 101", "--backend", "nope", "--plot", "top.txt"),
                   "--plot top.txt", ".png")
    folder = tmp_path / "figs"
    folder.mkdir()
    one_line_error(*invoke("scenarios", "show", SMALL_ROOM, "--plot", f"{folder}/"), "a folder")
    assert list(folder.iterdir()) == [] and not (tmp_path / "figs.png").exists()
    code, output = invoke("scenarios", "show", SMALL_ROOM, "--plot", "name")
    assert code == 0 and (tmp_path / "name.png").exists() and "name.png" in output, output
    run = tmp_path / "run"
    assert invoke(*DRIVE, "--planner", "oracle", "--out", str(run))[0] == 0
    one_line_error(*invoke("score", str(run), "--plot", "charts.png"), "folder")
    assert not (tmp_path / "charts.png").exists()


# --- 16. backends and planners that cannot work cost no run ------------------------------------------------


@pytest.mark.parametrize("backend,env,needle", [
    ("openai:m@http://256.1.1.1/v1", {}, "not an IPv4 address"),
    ("openai:m@ftp://example.org/v1", {}, "scheme 'ftp'"),
    ("openai:m@http://127.0.0.1:70000/v1", {}, "out of range"),
    ("ollama", {"OLLAMA_HOST": "bad host!"}, "no valid host"),
])
def test_unusable_backend_urls_are_bad_input(tmp_path: Path, backend: str, env: dict[str, str],
                                             needle: str) -> None:
    out = tmp_path / "run"
    one_line_error(*invoke(*DRIVE, "--planner", "stepwise", "--backend", backend, "--out", str(out), env=env),
                   needle)
    assert not out.exists()


def test_planner_that_cannot_run_on_the_scenario(tmp_path: Path) -> None:
    out = tmp_path / "run"
    one_line_error(*invoke("drive", "--scenario", "factory", "--task-id", "T1", "--planner", "waypoints",
                           "--backend", "replay:nowhere", "--out", str(out)), "corridors")
    assert not out.exists()


# --- 17. the small ones --------------------------------------------------------------------------------------


def test_small_usability_errors(tmp_path: Path) -> None:
    one_line_error(*invoke("drive", "--task", "", "--out", str(tmp_path / "r")), "--task: empty task text")
    one_line_error(*invoke(*DRIVE, "--lidar-fov", "0", "--out", str(tmp_path / "r")), "--lidar-fov:")
    code, output = invoke(*DRIVE, "--lidar-fov", "0", "--out", str(tmp_path / "r"))
    assert "--lidar-fov-deg" not in output
    one_line_error(*invoke(*DRIVE, "--sensing", ",,lidar,,lidar", "--out", str(tmp_path / "r")), "lidar")
    one_line_error(*invoke("ablate", "--scenario", SMALL_ROOM, "--name", "/etc", "--dry-run"), "plain folder name")
    one_line_error(*invoke("ablate", "--scenario", SMALL_ROOM, "--sensing", "lidar+lidar", "--dry-run"), "sensor")
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize("flag,value,needle", [("--backend", "nope", "unknown backend 'nope'"),
                                               ("--prompt", "../../etc/passwd", "prompt")])
def test_dry_run_validates_like_the_real_run(tmp_path: Path, flag: str, value: str, needle: str) -> None:
    args = ["ablate", "--scenario", SMALL_ROOM, "--tasks", "T1", "--planner", "stepwise", flag, value,
            "--out", str(tmp_path / "ab")]
    one_line_error(*invoke(*args, "--dry-run"), needle)
    one_line_error(*invoke(*args), needle)
    assert not (tmp_path / "ab").exists()


def test_an_hour_of_audio_is_refused_from_its_header(tmp_path: Path) -> None:
    path = tmp_path / "hour.wav"
    with wave.open(str(path), "wb") as wav:  # 1 h of silence, 8 kHz 8-bit mono (29 MB)
        wav.setnchannels(1)
        wav.setsampwidth(1)
        wav.setframerate(8000)
        wav.writeframes(b"\x80" * (8000 * 3600))
    one_line_error(*invoke("transcribe", str(path)), "3600 s of audio")


def test_pybullet_banner_is_not_printed_before_an_error(tmp_path: Path) -> None:
    result = subprocess.run([sys.executable, "-c", ENTRY, *DRIVE, "--planner", "oracle", "--obstacle", "1e6,1e6",
                             "--out", str(tmp_path / "run")], capture_output=True, text=True, timeout=120,
                            env={**os.environ})
    assert result.returncode == 2 and "pybullet build time" not in result.stderr + result.stdout
    assert len(result.stderr.strip().splitlines()) == 1, result.stderr


@pytest.mark.slow  # the backend's real backoff: about 10-25 s
def test_each_retry_is_printed_even_when_quiet(tmp_path: Path) -> None:
    """A server that does not answer used to block silently under --quiet; now each retry is one line."""
    result = subprocess.run([sys.executable, "-c", ENTRY, *DRIVE, "--planner", "stepwise", "--sensing", "lidar",
                             "--backend", "openai:m@http://127.0.0.1:9/v1", "--max-iterations", "1", "--quiet",
                             "--out", str(tmp_path / "run")], capture_output=True, text=True, timeout=300)
    retries = [line for line in result.stderr.splitlines() if "retry" in line]
    assert [line.split("retry ")[1].split(" ")[0] for line in retries] == ["1/4", "2/4", "3/4", "4/4"], result.stderr
    assert all(line.startswith("llmnav: openai: connection failed") for line in retries)
