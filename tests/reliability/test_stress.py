"""The stress flat (tests/nav/stress_flat.yaml): tight doorways, wall ends, low obstacles, thin legs and
three times the factory's odometry drift. Nothing may touch anything, and the planners that know the map
must still arrive.

The default suite drives two episodes; `make reliability` drives every task and start pose with the
`oracle` and `frontier` baselines and the hybrid with oracle answers and with `policy:first`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from llmnav.planners.base import drive_options
from llmnav.runs.runner import EpisodeSpec, run_episode
from llmnav.world.scenario import load_scenario

STRESS = Path(__file__).parents[1] / "nav" / "stress_flat.yaml"
CATEGORY = "stress: collisions"


def drive(tmp_path: Path, planner: str, task: str, pose: int, backend: str = "policy:first") -> dict[str, Any]:
    spec = EpisodeSpec(
        scenario=str(STRESS),
        task_id=task,
        start_pose=pose,
        options=drive_options(planner=planner, seed=pose),
        backend=backend,
        out_dir=tmp_path / f"{planner}-{backend.replace(':', '-')}-{task}-{pose}",
    )
    return run_episode(spec)


def run_suite(tmp_path: Path, episodes: list[tuple[str, str, str, int]], tally: Any) -> list[dict[str, Any]]:
    summaries = []
    for planner, backend, task, pose in episodes:
        summary = drive(tmp_path, planner, task, pose, backend)
        summaries.append({"planner": planner, "backend": backend, "task": task, "pose": pose, **summary})
    touched = [s for s in summaries if s.get("collisions")]
    tally.add(CATEGORY, tried=len(summaries), unsafe=sum(int(s["collisions"]) for s in touched))
    assert not touched, [(s["planner"], s["backend"], s["task"], s["pose"], s.get("reason")) for s in touched]
    return summaries


def test_two_stress_episodes_touch_nothing_and_arrive(tmp_path: Path, tally: Any) -> None:
    episodes = [("oracle", "policy:first", "S1", 2), ("frontier", "policy:first", "S2", 1)]
    for summary in run_suite(tmp_path, episodes, tally):
        assert summary["success"], (summary["planner"], summary.get("reason"))


@pytest.mark.slow
@pytest.mark.reliability
def test_every_stress_episode_touches_nothing_and_the_baselines_arrive(tmp_path: Path, tally: Any) -> None:
    scenario = load_scenario(STRESS)
    poses = [(t.id, i) for t in scenario.tasks for i in range(1, len(scenario.start_poses(t)) + 1)]
    runs = [
        ("oracle", "policy:first"),
        ("frontier", "policy:first"),
        ("hybrid", "policy:oracle"),
        ("hybrid", "policy:first"),
    ]
    episodes = [(planner, backend, task, pose) for planner, backend in runs for task, pose in poses]
    summaries = run_suite(tmp_path, episodes, tally)
    baselines = [s for s in summaries if s["planner"] in ("oracle", "frontier")]
    arrived = sum(bool(s["success"]) for s in baselines)
    tally.note(CATEGORY, "baselines arrived", f"{arrived}/{len(baselines)}")
    assert arrived == len(baselines), [
        (s["planner"], s["task"], s["pose"], s.get("reason")) for s in baselines if not s["success"]
    ]
