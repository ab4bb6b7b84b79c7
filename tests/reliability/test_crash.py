"""Crash safety: `llmnav drive` killed with SIGKILL at random moments, and `llmnav ablate` killed and resumed.

Properties: whatever the moment, the run folder holds a log that `read_run`, `summarize_run` and
`llmnav score` accept (complete lines valid, at most the last one torn; every image an observation names
exists; summary.json absent or whole); an ablation killed and resumed ends with every episode done exactly
once, and the episodes finished before the kill are kept byte for byte (not lost, not rerun).
"""

from __future__ import annotations

import hashlib
import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from llmnav.cli import app
from llmnav.planners.stepwise.answers import step_answer
from llmnav.runs.runlog import RUN_FILE, SUMMARY_FILE, SUPERSEDED_FILE, RunLog, read_run
from llmnav.scoring.metrics import summarize_run
from llmnav.world.scenario import load_scenario

CATEGORY = "crash safety"
SMALL_ROOM = str(Path(__file__).parents[1] / "runner" / "small_room.yaml")
LLMNAV = str(Path(sys.executable).parent / "llmnav")


def answer(command: str, parameters: float) -> str:
    return f"```json\n{json.dumps(step_answer(command, parameters))}\n```"


def replay_script(folder: Path, steps: int) -> str:
    """A hand-written run log of `steps` answers (turns and short moves) for the loose replay backend."""
    with RunLog(folder, {"note": "scripted replies for kill tests"}) as log:
        for i in range(steps):
            text = answer("ROTATE_LEFT", 40) if i % 3 else answer("FRONT", 0.4)
            log.event("llm_call", step=i + 1, purpose="action", request={"messages": []},
                      reply={"text": text, "latency_s": 0.0, "model": "script"})
    return f"replay:{folder}?loose"


def drive_command(backend: str, out: Path, sensing: str) -> list[str]:
    return [LLMNAV, "drive", "--planner", "stepwise", "--backend", backend, "--scenario", SMALL_ROOM,
            "--task-id", "T1", "--sensing", sensing, "--max-iterations", "20", "--out", str(out), "--quiet"]


def check_leftovers(out: Path) -> list[str]:
    """What is wrong with a killed run folder (empty list: nothing)."""
    problems: list[str] = []
    record = read_run(out)
    summarize_run(record, load_scenario(SMALL_ROOM))
    for obs in record.of_type("observation"):
        if obs.get("image") and not (out / "images" / f"{obs['image']}.jpg").exists():
            problems.append(f"observation names a missing image {obs['image']}")
    summary = out / SUMMARY_FILE
    if summary.exists():
        json.loads(summary.read_text())
    if record.torn_lines > 1:
        problems.append(f"{record.torn_lines} torn lines")
    result = CliRunner().invoke(app, ["score", str(out), "--format", "json"])
    if result.exit_code != 0:
        problems.append(f"score exit {result.exit_code}: {result.output.strip()[-300:]}")
    return problems


def kill_drives(tmp_path: Path, kills: int, seed: int, tally: Any) -> None:
    rng = random.Random(seed)
    backend = replay_script(tmp_path / "script", 30)
    # a reference run: how long the episode lasts once its log exists
    ref = tmp_path / "reference"
    started = time.perf_counter()
    proc = subprocess.Popen(drive_command(backend, ref, "lidar"), stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    while not (ref / RUN_FILE).exists() and proc.poll() is None:
        time.sleep(0.002)
    t_log = time.perf_counter()
    proc.wait(timeout=300)
    episode_s = time.perf_counter() - t_log
    assert read_run(ref).complete, "the reference run did not finish"
    tally.note(CATEGORY, "episode length [s]", round(episode_s, 2))
    tally.note(CATEGORY, "process start to log [s]", round(t_log - started, 2))

    points = 0
    lost = 0
    problems: list[str] = []
    moments: list[float] = []
    attempts = 0
    while points < kills:
        attempts += 1
        assert attempts < kills * 3, "too many kills landed outside the episode"
        out = tmp_path / f"kill-{points:03d}"
        sensing = "lidar,image" if points % 5 == 1 else "lidar"
        proc = subprocess.Popen(drive_command(backend, out, sensing), stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL)
        # a few kills right as the log appears, the rest anywhere in the episode
        delay = rng.choice([0.0, 0.001]) if points % 10 == 0 else rng.uniform(0.0, episode_s * 1.05)
        while not (out / RUN_FILE).exists() and proc.poll() is None:
            time.sleep(0.0005)
        time.sleep(delay)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
        if proc.returncode != -signal.SIGKILL:  # finished before the kill: not a kill point
            continue
        points += 1
        moments.append(delay)
        try:
            found = check_leftovers(out)
        except Exception as err:  # noqa: BLE001 - an unreadable log is what this test hunts
            found = [f"{type(err).__name__}: {err}"]
        if found:
            lost += 1
            problems.append(f"kill {points} at +{delay:.3f} s: {found}")
    tally.add(CATEGORY, tried=points, lost=lost)
    prior = tally.notes.get(CATEGORY, {}).get("drive kill points", 0)
    tally.note(CATEGORY, "drive kill points", prior + points)
    assert not problems, problems[:5]


def test_killed_drives_leave_readable_logs_quick(tmp_path: Path, tally: Any) -> None:
    kill_drives(tmp_path, 4, seed=1, tally=tally)


@pytest.mark.slow
@pytest.mark.reliability
def test_killed_drives_leave_readable_logs_full(tmp_path: Path, tally: Any) -> None:
    kill_drives(tmp_path, 100, seed=2, tally=tally)


# --- ablations ----------------------------------------------------------------------------------------


def ablate_command(out: Path, workers: int) -> list[str]:
    return [LLMNAV, "ablate", "--scenario", SMALL_ROOM, "--tasks", "T1", "--poses", "1,2", "--trials", "3",
            "--planner", "oracle,frontier", "--out", str(out), "--workers", str(workers)]


def finished_runs(root: Path) -> dict[str, str]:
    """Episode folder → hash of run.jsonl + summary.json, for every folder with a summary (not superseded)."""
    done = {}
    for summary in root.glob(f"*/{SUMMARY_FILE}"):
        if (summary.parent / SUPERSEDED_FILE).exists():
            continue
        data = (summary.parent / RUN_FILE).read_bytes() + summary.read_bytes()
        done[summary.parent.name] = hashlib.sha256(data).hexdigest()
    return done


def kill_and_resume_ablation(tmp_path: Path, rounds: int, seed: int, workers: int, tally: Any) -> None:
    rng = random.Random(seed)
    out = tmp_path / f"ablation-w{workers}"
    kills = 0
    for _ in range(rounds):
        proc = subprocess.Popen(ablate_command(out, workers), stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL)
        # wait until at least one more episode has finished, then a random extra moment
        before = len(finished_runs(out)) if out.exists() else 0
        deadline = time.perf_counter() + 120
        while proc.poll() is None and time.perf_counter() < deadline:
            if out.exists() and len(finished_runs(out)) > before:
                break
            time.sleep(0.01)
        time.sleep(rng.uniform(0.0, 1.5))
        if proc.poll() is not None:
            break  # the sweep finished: nothing left to kill
        os.killpg(proc.pid, signal.SIGKILL) if workers > 1 else proc.kill()
        proc.wait(timeout=30)
        kills += 1
        kept = finished_runs(out)
        resumed = subprocess.run(ablate_command(out, 1)[:-2] + ["--workers", "1"], capture_output=True,
                                 text=True, timeout=600)
        assert resumed.returncode in (0, 1), resumed.stderr[-500:]
        after = finished_runs(out)
        manifest = json.loads((out / "manifest.json").read_text())
        lost = [name for name, digest in kept.items() if after.get(name) != digest]
        keys = [e["key"] for e in manifest["episodes"]]
        dirs = {e["dir"] for e in manifest["episodes"]}
        # folders of cut-short episodes are kept (never deleted), marked superseded
        on_disk = {p.name for p in out.iterdir() if p.is_dir() and not (p / SUPERSEDED_FILE).exists()}
        # counted with the data-safety cases: the table's "results lost or mislabelled" row covers kills
        tally.add("data safety", tried=1, lost=len(lost))
        assert not lost, f"episodes finished before the kill were lost or rerun: {lost}"
        assert len(keys) == len(set(keys)) == manifest["size"] == manifest["done"] == 12, manifest
        assert all(e["status"] == "done" for e in manifest["episodes"])
        assert on_disk == dirs, on_disk ^ dirs  # no duplicate or stray episode folders
        assert set(after) == dirs
        # the next round starts the sweep afresh in a new folder only if this one is finished
        out = tmp_path / f"ablation-w{workers}-{kills}"
    prior = tally.notes.get(CATEGORY, {}).get("ablation kills", 0)
    tally.note(CATEGORY, "ablation kills", prior + kills)
    assert kills > 0


def test_killed_ablation_resumes_without_loss_quick(tmp_path: Path, tally: Any) -> None:
    kill_and_resume_ablation(tmp_path, 1, seed=3, workers=1, tally=tally)


@pytest.mark.slow
@pytest.mark.reliability
def test_killed_ablation_resumes_without_loss_full(tmp_path: Path, tally: Any) -> None:
    kill_and_resume_ablation(tmp_path, 3, seed=4, workers=1, tally=tally)
