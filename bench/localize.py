"""Localization: the CPU time of one scan match and the pose error it leaves, in real hybrid episodes.

The hybrid planner (sensed information, oracle answers) runs factory tasks from their first start pose;
every `Localizer.update` it makes is timed with the process's CPU clock (one core's work, whatever else
the machine runs), and each run's `pose_error_m` is read from its summary.
Targets (issue "Buildings nobody tuned to"): ≤ 5 ms per scan on one core; pose error at the end of an
episode median ≤ 0.10 m, max ≤ 0.30 m.
Quick mode: one task, three decisions; no target is judged.
"""

from __future__ import annotations

import statistics
import tempfile
import time
from pathlib import Path
from typing import Any
from unittest import mock

from bench import judged
from llmnav.nav.localize import Localizer
from llmnav.planners.base import drive_options
from llmnav.runs.runner import EpisodeSpec, run_episode

SCAN_TARGET_MS = 1e3 * 0.005  # [ms] per scan on one core
FINAL_MEDIAN_TARGET_M = 0.10  # [m]
FINAL_MAX_TARGET_M = 0.30  # [m]
TASKS = [f"T{i}" for i in range(1, 11)]


def _episodes(tasks: list[str], max_iterations: int) -> tuple[list[float], list[dict[str, Any]]]:
    """CPU milliseconds of every scan match, and each episode's summary."""
    timings: list[float] = []
    original = Localizer.update

    def timed(self: Localizer, *args: Any, **kwargs: Any) -> Any:
        start = time.process_time()
        result = original(self, *args, **kwargs)
        timings.append((time.process_time() - start) * 1000.0)
        return result

    summaries = []
    with tempfile.TemporaryDirectory() as tmp, mock.patch.object(Localizer, "update", timed):
        for task in tasks:
            spec = EpisodeSpec(
                scenario="factory",
                task_id=task,
                backend="policy:oracle",
                options=drive_options(planner="hybrid", max_iterations=max_iterations),
                out_dir=Path(tmp) / task,
                plots=False,
            )
            summaries.append(run_episode(spec))
    return timings, summaries


def main(quick: bool = False) -> None:
    """Print the localization table (quick: one short episode, not a measurement)."""
    tasks, iterations = (TASKS[:1], 3) if quick else (TASKS, 30)
    timings, summaries = _episodes(tasks, iterations)
    errors = [s["pose_error_m"] for s in summaries if s.get("pose_error_m")]
    finals = [e["final"] for e in errors]
    worst = [e["max"] for e in errors]
    ordered = sorted(timings)
    p95 = ordered[min(len(ordered) - 1, int(0.95 * len(ordered)))]
    median_ms = statistics.median(timings)
    mode = ", quick: not a measurement" if quick else ""
    print(f"localize: {len(timings)} scans matched in {len(summaries)} factory episodes (hybrid, sensed){mode}")
    verdict = judged("meets" if median_ms <= SCAN_TARGET_MS else "ABOVE TARGET", quick)
    print(f"  CPU per scan [ms]  median {median_ms:.2f}  p95 {p95:.2f}  max {ordered[-1]:.2f}  ({verdict})")
    final_median = statistics.median(finals)
    ok = final_median <= FINAL_MEDIAN_TARGET_M and max(finals) <= FINAL_MAX_TARGET_M
    print(
        f"  pose error at the end [m]  median {final_median:.3f}  max {max(finals):.3f}  "
        f"({judged('meets' if ok else 'MISSES', quick)}); largest during a run {max(worst):.3f}"
    )
