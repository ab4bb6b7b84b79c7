"""Recorded runs of every planner without a model replay to the same events: the speed-ups change no result.

Each episode below ran once and its log was reduced to a digest: every event but the configuration, with
wall-clock times and model latencies dropped (poses, observations with their detections and image hashes,
requests, decisions, actions, the end), plus the summary's outcome, score and path. A change to the
simulation, the sensors or the planning grids that moves one pose, one detection or one menu changes the
digest. `LLMNAV_WRITE_GOLDEN=1` rewrites `golden_runs.json` (only for a change that is meant to change results).
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Any

import pytest

from llmnav.planners.base import drive_options
from llmnav.runs.runlog import read_run
from llmnav.runs.runner import EpisodeSpec, run_episode

GOLDEN = Path(__file__).with_name("golden_runs.json")

# name -> EpisodeSpec fields; backends are policies or none, so the runs are fast and exact.
EPISODES: dict[str, dict[str, Any]] = {
    "hybrid-sensed-factory": {
        "scenario": "factory",
        "task_id": "T1",
        "backend": "policy:first",
        "options": {"planner": "hybrid", "max_iterations": 10},
    },
    "hybrid-map-corridor": {
        "scenario": "corridor_a",
        "task_text": "Go to room 101",
        "backend": "policy:keyword",
        "options": {"planner": "hybrid", "max_iterations": 4},
    },
    "stepwise-factory": {
        "scenario": "factory",
        "task_id": "T1",
        "backend": "policy:first",
        "options": {"planner": "stepwise", "max_iterations": 5},
    },
    "waypoints-corridor": {
        "scenario": "corridor_a",
        "task_text": "Go to room 101",
        "backend": "policy:keyword",
        "options": {"planner": "waypoints"},
    },
    "oracle-factory": {"scenario": "factory", "task_id": "T1", "options": {"planner": "oracle"}},
    "frontier-factory": {"scenario": "factory", "task_id": "T1", "options": {"planner": "frontier"}},
    "fsm-maze": {
        "scenario": "maze_arena",
        "task_id": "M1",
        "options": {"planner": "fsm", "assist": "none", "seed": 1},
    },
}
# Fields measured on the wall clock: they differ from run to run.
WALL_CLOCK = ("t_wall", "latency_s", "wall_time_s", "planning_time_s", "tick_latency_ms")
SUMMARY_KEYS = ("outcome", "reason", "iterations", "score", "success", "path_length_m", "collisions", "final_pose")


def _without_timing(value: Any) -> Any:
    """The value with wall-clock fields removed at any depth."""
    if isinstance(value, dict):
        return {k: _without_timing(v) for k, v in value.items() if k not in WALL_CLOCK}
    if isinstance(value, list):
        return [_without_timing(v) for v in value]
    return value


def run_digest(name: str, out: Path) -> dict[str, Any]:
    """Run one episode of `EPISODES` into `out` and reduce it to what must not change."""
    setup = EPISODES[name]
    spec = EpisodeSpec(
        scenario=setup["scenario"],
        task_id=setup.get("task_id"),
        task_text=setup.get("task_text"),
        backend=setup.get("backend", "local"),
        options=drive_options(**setup["options"]),
        out_dir=out,
        plots=False,
    )
    summary = run_episode(spec)
    events = [_without_timing(e) for e in read_run(out).events if e.get("type") != "config"]
    text = json.dumps(events, sort_keys=True, separators=(",", ":"))
    poses = [e["pose"] for e in events if e["type"] == "pose"]
    return {
        "events": len(events),
        "poses": len(poses),
        "events_sha256": hashlib.sha256(text.encode()).hexdigest(),
        "summary": {k: summary.get(k) for k in SUMMARY_KEYS},
        "planner_metrics": _without_timing(summary.get("planner_metrics")),
    }


@pytest.mark.parametrize("name", list(EPISODES))
def test_run_replays_to_the_recorded_events(name: str, tmp_path: Path) -> None:
    digest = run_digest(name, tmp_path / name)
    if os.environ.get("LLMNAV_WRITE_GOLDEN"):
        recorded = json.loads(GOLDEN.read_text()) if GOLDEN.exists() else {}
        recorded[name] = digest
        GOLDEN.write_text(json.dumps(recorded, indent=1, sort_keys=True) + "\n")
        pytest.skip("golden digest written")
    expected = json.loads(GOLDEN.read_text())[name]
    assert digest["summary"] == expected["summary"]
    assert digest["planner_metrics"] == expected["planner_metrics"]
    assert (digest["events"], digest["poses"]) == (expected["events"], expected["poses"])
    assert digest["events_sha256"] == expected["events_sha256"]
