"""Test helpers for tests/score: a tiny scenario, run folders written with the real RunLog, a fake runner.

A module (not a test file) so spawned worker processes can import the fake episode function by name.
"""

from __future__ import annotations

import hashlib
import math
import time
from pathlib import Path
from typing import Any

from llmnav.runs.runlog import SUMMARY_FILE, RunLog, read_run, write_json_atomic
from llmnav.world.scenario import Scenario, parse_scenario

SCENARIO_DATA: dict[str, Any] = {
    "name": "tiny",
    "robot": "pr2",
    "bounds": {"x": [-10, 10], "y": [-10, 10]},
    "objects": [
        {"id": "pellets", "label": "pile of pellets", "center": [5.0, 0.0], "size": [1.0, 1.0]},
        {"id": "boxes", "label": "dark brown boxes", "center": [-5.0, 0.0], "size": [1.0, 1.0]},
    ],
    "tasks": [
        {
            "id": "T1",
            "text": "Go to the pile of pellets",
            "targets": [{"object": "pellets"}],
            "start_poses": [{"x": 0, "y": 0}, {"x": 0, "y": 3}],
        },
        {
            "id": "T2",
            "text": "Go to pellets or boxes",
            "targets": [{"object": "pellets"}, {"object": "boxes"}],
            "difficulty": "hard",
            "start_poses": [{"x": 0, "y": 0}],
        },
        {
            "id": "T6",
            "text": "Make a 360-degree turn",
            "kind": "rotate",
            "difficulty": "easy",
            "start_poses": [{"x": 0, "y": 0}],
        },
        {
            "id": "T7",
            "text": "Look around",
            "kind": "explore",
            "difficulty": "easy",
            "start_poses": [{"x": 0, "y": 0}],
        },
    ],
}


def write_scenario_file(path: Path) -> Path:
    """The tiny scenario as a YAML file (what a run's `scenario_file` points at)."""
    import yaml

    path.write_text(yaml.safe_dump(SCENARIO_DATA))
    return path


def tiny_scenario() -> Scenario:
    return parse_scenario(SCENARIO_DATA, "tiny.yaml")


def config_for(
    task_id: str,
    *,
    planner: str = "stepwise",
    backend: str | None = "replay:x",
    options: dict[str, Any] | None = None,
    start_pose_index: int = 1,
    seed: int = 0,
    scenario: str = "tiny",
    scenario_file: Path | None = None,
    condition: str | None = None,
) -> dict[str, Any]:
    sc = tiny_scenario()
    task = sc.task(task_id)
    opts = {
        "planner": planner,
        "sensing": ["lidar", "image"],
        "lidar_sectors": 8,
        "prompt": "full",
        "history": "all",
        "self_check": False,
        "assist": "none",
        "seed": seed,
    }
    opts.update(options or {})
    start = sc.start_poses(task)[start_pose_index - 1]
    return {
        "scenario": scenario,
        "scenario_file": str(scenario_file) if scenario_file else None,
        "task": {
            "id": task.id,
            "text": task.text,
            "kind": task.kind,
            "difficulty": task.difficulty,
            "targets": [t.model_dump() for t in task.targets],
        },
        "start_pose_index": start_pose_index,
        "start_pose": [start.x, start.y, math.radians(start.yaw_deg)],
        "planner": planner,
        "backend": backend,
        "options": opts,
        "seed": seed,
        **({"condition_hash": condition} if condition else {}),
    }


def write_run(
    run_dir: Path,
    config: dict[str, Any],
    poses: list[list[float]],
    *,
    outcome: str | None = "completed",
    latencies: tuple[float, ...] = (1.0,),
    guards: tuple[str, ...] = (),
    metrics: dict[str, Any] | None = None,
    summary: bool = False,
    scenario: Scenario | None = None,
) -> Path:
    """A run folder: llm calls, guard verdicts, one action per pose sample, and an end event unless None."""
    with RunLog(run_dir, config) as log:
        for step, latency in enumerate(latencies):
            log.event(
                "llm_call",
                step=step,
                purpose="action",
                request={"messages": []},
                reply={"text": "{}", "latency_s": latency, "model": "fake"},
            )
        for step, outcome_name in enumerate(guards):
            log.event("guard", step=step, outcome=outcome_name, error=None, attempt=1)
        for step, pose in enumerate(poses):
            log.sim_time = float(step)
            log.event("pose", pose=pose)
            if step:
                log.event(
                    "action",
                    step=step,
                    command="FRONT",
                    parameters=1.0,
                    pose_before=poses[step - 1],
                    pose_after=pose,
                    collided=False,
                    collision_with=None,
                )
        if outcome is not None:
            log.event("end", outcome=outcome, reason="test", metrics=metrics or {})
    if summary and outcome is not None:
        from llmnav.scoring.metrics import summarize_run

        summary_data = summarize_run(read_run(run_dir), scenario or tiny_scenario())
        write_json_atomic(run_dir / SUMMARY_FILE, summary_data)
    return run_dir


# --- the fake episode function the ablation tests inject -----------------------------------------


def fake_episode(spec: Any) -> dict[str, Any]:
    """A deterministic episode: the final pose depends only on (task, pose, options seed, sectors)."""
    from llmnav.scoring.metrics import summarize_run

    sc = tiny_scenario()
    task_id = spec.task_id or "T1"
    options = spec.options.model_dump(mode="json")
    seed = int(options.get("seed", 0))
    key = f"{task_id}|{spec.start_pose}|{seed}|{options.get('lidar_sectors')}"
    digest = hashlib.sha256(key.encode()).digest()
    x_end = 1.0 + digest[0] / 255 * 5.0  # [m] somewhere between 1 and 6 m along x
    config = config_for(
        task_id,
        planner=options.get("planner", "stepwise"),
        backend=spec.backend,
        options=options,
        start_pose_index=spec.start_pose,
        seed=seed,
        condition=getattr(spec, "condition", None),
    )
    poses = [[0.0, 0.0, 0.0], [x_end / 2, 0.0, 0.0], [x_end, 0.0, 0.0]]
    time.sleep(0.01)
    run_dir = Path(spec.out_dir)
    write_run(run_dir, config, poses, latencies=(0.5 + digest[1] / 255,))
    summary = summarize_run(read_run(run_dir), sc)
    write_json_atomic(run_dir / SUMMARY_FILE, summary)
    return summary


class InterruptingRunner:
    """`fake_episode`, but 'killed' in episode number `kill_at` (1-based): half a log, then Ctrl-C."""

    def __init__(self, kill_at: int) -> None:
        self.kill_at = kill_at
        self.calls = 0

    def __call__(self, spec: Any) -> dict[str, Any]:
        self.calls += 1
        if self.calls == self.kill_at:
            options = spec.options.model_dump(mode="json")
            config = config_for(
                spec.task_id,
                options=options,
                start_pose_index=spec.start_pose,
                seed=options["seed"],
                backend=spec.backend,
                condition=getattr(spec, "condition", None),
            )
            write_run(Path(spec.out_dir), config, [[0.0, 0.0, 0.0]], outcome=None)
            with open(Path(spec.out_dir) / "run.jsonl", "a") as f:
                f.write('{"type": "pose", "pose": [0.5,')
            raise KeyboardInterrupt
        return fake_episode(spec)


class CountingRunner:
    """`fake_episode`, counting which episodes it ran."""

    def __init__(self) -> None:
        self.ran: list[str] = []

    def __call__(self, spec: Any) -> dict[str, Any]:
        self.ran.append(Path(spec.out_dir).name)
        return fake_episode(spec)


def served_episode(spec: Any) -> dict[str, Any]:
    """`fake_episode` in a worker of the shared-model layout, after one answer from the shared server.

    Fails unless the worker's `local` backend reaches the sweep's server (not a copy of its own).
    """
    from llmnav.backends.base import ChatRequest, Message
    from llmnav.backends.local import LocalBackend
    from llmnav.backends.served import ServedEngine

    backend = LocalBackend(None)
    if not isinstance(backend.load(), ServedEngine):
        raise RuntimeError("the worker loaded its own model")
    backend.chat(ChatRequest(messages=(Message("user", "Say OK."),), temperature=0.0, max_tokens=2))
    return fake_episode(spec)
