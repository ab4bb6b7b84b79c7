"""The hybrid planner's cost in `sensed` mode against `oracle` (how it planned before the modes existed).

Factory tasks T5 and T8 from start poses 1 and 2, driven by a zero-latency backend that always
answers option 1 (the nearest place in the neutral menu), 6 decisions at most, detections sensed, no plots.
Sensed planning rebuilds its grids from the robot's own LiDAR map at every decision; the target is
sensed / oracle ≤ 1.5 in wall time per episode. Set BENCH_INFORMATION_REPEATS (default 1) for medians.
Quick mode: T5 from pose 1 only, 2 decisions at most; no target is judged.
"""

from __future__ import annotations

import json
import os
import statistics
import tempfile
import time
from pathlib import Path

from bench import judged, quick_from_env
from llmnav.backends.base import Backend, ChatRequest, ChatResult
from llmnav.planners.base import drive_options
from llmnav.runs.runner import EpisodeSpec, run_episode

TARGET_RATIO = 1.5
EPISODES = [(task, pose) for task in ("T5", "T8") for pose in (1, 2)]
DECISIONS = 6  # [decisions] at most an episode
QUICK_EPISODES = EPISODES[:1]
QUICK_DECISIONS = 2


class FirstOption(Backend):
    """Always option 1, at once."""

    name = "first-option"
    deterministic = True

    def __init__(self) -> None:
        super().__init__(None)

    def chat(self, request: ChatRequest) -> ChatResult:
        return ChatResult(json.dumps({"option": 1, "reasoning": "first"}), 0.0, "first-option")


def sweep(
    information: str, root: Path, episodes: list[tuple[str, int]] = EPISODES, cap: int = DECISIONS
) -> tuple[float, int]:
    """Seconds per episode and decisions made over the episode list."""
    decisions = 0
    start = time.perf_counter()
    for task, pose in episodes:
        options = drive_options(
            planner="hybrid", information=information, sensing=("lidar", "detections"), max_iterations=cap
        )  # type: ignore[arg-type]
        spec = EpisodeSpec(
            scenario="factory",
            task_id=task,
            start_pose=pose,
            options=options,
            backend="first-option",
            out_dir=root / f"{information}-{task}-{pose}",
            plots=False,
        )
        decisions += int(run_episode(spec, backend_obj=FirstOption()).get("iterations") or 0)
    return (time.perf_counter() - start) / len(episodes), decisions


def main(quick: bool = False) -> None:
    """Print the table (quick: one short episode a mode, not a measurement)."""
    repeats = 1 if quick else int(os.environ.get("BENCH_INFORMATION_REPEATS", "1"))
    episodes, cap = (QUICK_EPISODES, QUICK_DECISIONS) if quick else (EPISODES, DECISIONS)
    per_episode: dict[str, list[float]] = {"oracle": [], "sensed": []}
    decisions: dict[str, int] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(repeats):
            for mode in per_episode:
                seconds, decisions[mode] = sweep(mode, Path(tmp) / str(r), episodes, cap)
                per_episode[mode].append(seconds)
    oracle, sensed = (statistics.median(per_episode[m]) for m in ("oracle", "sensed"))
    ratio = sensed / oracle
    # The two modes take different decisions (different menus), so the cost per decision is shown too.
    per_decision = {m: statistics.median(per_episode[m]) * len(episodes) / max(1, decisions[m]) for m in decisions}
    print(f"[bench.information] hybrid, {len(episodes)} factory episodes, median of {repeats}")
    for mode, seconds in (("oracle", oracle), ("sensed", sensed)):
        rate = per_decision[mode]
        print(f"  {mode:7s} {seconds:6.2f} s/episode  {rate:5.2f} s/decision  ({decisions[mode]} decisions)")
    verdict = judged("ok" if ratio <= TARGET_RATIO else "OVER", quick)
    per_decision_ratio = per_decision["sensed"] / per_decision["oracle"]
    print(f"  sensed / oracle = {ratio:.2f} per episode, {per_decision_ratio:.2f} per decision")
    print(f"  target per episode ≤ {TARGET_RATIO}: {verdict}")


if __name__ == "__main__":
    main(quick=quick_from_env())
