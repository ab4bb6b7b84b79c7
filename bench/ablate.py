"""Ablation throughput: episodes per minute with 1 and 2 worker processes, and the full protocol's time.

A 40-episode ablation on the factory (LiDAR sectors 3 vs 8 × all 10 tasks × start poses 1–2), stepwise
planner with LiDAR + 640×480 camera, driven by a deterministic scripted backend that answers at once (a
fixed plan of turns and moves, then COMPLETE), so the numbers are llmnav's own cost: simulation, sensors,
prompts, guard, logs, summaries and the process pool. Targets: speed-up of 2 workers over 1 ≥ 1.8×, and the
full factory protocol (10 tasks × 5 poses × 4 trials = 200 episodes) projected ≤ 5 min with 2 workers.
Set BENCH_ABLATE_REPEATS (default 1) for medians over several sweeps.
"""

from __future__ import annotations

import os
import resource
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

from llmnav.ablate import grid_from_mapping, plan, run
from llmnav.backends.base import Backend, ChatRequest, ChatResult
from llmnav.runner import EpisodeSpec, run_episode

TARGET_SPEEDUP = 1.8
TARGET_PROTOCOL_S = 300.0  # [s] 200 episodes with 2 workers
PROTOCOL_EPISODES = 200
GRID: dict[str, Any] = {
    "scenario": "factory",
    "tasks": "all",
    "poses": [1, 2],
    "trials": 1,
    "lidar_sectors": [3, 8],
    "planner": ["stepwise"],
    "sensing": ["lidar+image"],
    "options": {"max_iterations": 12, "max_vetoes": 5},
}

# The scripted plan: (command, parameter); a vetoed move is answered with the next entry.
_PLAN: tuple[tuple[str, float], ...] = (
    ("ROTATE_LEFT", 45.0),
    ("FRONT", 1.0),
    ("ROTATE_RIGHT", 30.0),
    ("FRONT", 1.0),
    ("ROTATE_LEFT", 60.0),
    ("FRONT", 0.5),
    ("COMPLETE", 0.0),
)


class ScriptedBackend(Backend):
    """Plays `_PLAN` in order, one entry per call, then keeps answering COMPLETE; zero latency."""

    name = "scripted"
    deterministic = True

    def __init__(self) -> None:
        super().__init__(None)
        self.calls = 0

    def chat(self, request: ChatRequest) -> ChatResult:
        """The next planned action as the stepwise JSON answer."""
        command, parameter = _PLAN[min(self.calls, len(_PLAN) - 1)]
        self.calls += 1
        text = (
            '{"goal": "bench", "reasoning": "scripted", "scene_description": "-", '
            f'"action": {{"command": "{command}", "parameters": {parameter}}}}}'
        )
        return ChatResult(text=text, latency_s=0.0, model="scripted")


def scripted_episode(spec: EpisodeSpec) -> dict[str, Any]:
    """The ablation's runner: the real episode runner with a fresh scripted backend (picklable)."""
    return run_episode(spec, backend_obj=ScriptedBackend())


def _cpu_s() -> float:
    """CPU time [s] of this process plus its finished children (the pool's workers, once shut down)."""
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def _spin(seconds: float) -> float:
    """Busy-loop for `seconds` of wall time; the CPU time [s] this process got meanwhile."""
    start, cpu = time.perf_counter(), time.process_time()
    while time.perf_counter() - start < seconds:
        pass
    return time.process_time() - cpu


def cores_available(processes: int, seconds: float = 2.0) -> float:
    """Cores that `processes` busy processes actually get right now (other sessions share the machine)."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(processes, mp_context=multiprocessing.get_context("spawn")) as pool:
        return sum(pool.map(_spin, [seconds] * processes)) / seconds


def cpu_pressure() -> str:
    """Linux PSI: the share of the last 10 s in which some runnable task waited for a CPU."""
    try:
        line = Path("/proc/pressure/cpu").read_text().splitlines()[0]
    except (OSError, IndexError):
        return "n/a"
    fields = dict(part.split("=") for part in line.split()[1:])
    return f"{fields.get('avg10', '?')} %"


def _sweep(workers: int) -> tuple[float, float, int, int]:
    """Wall time [s], CPU time [s], episodes and successes of one sweep of the grid in a fresh folder."""
    with tempfile.TemporaryDirectory() as tmp:
        ablation = plan(grid_from_mapping(GRID, "bench"), Path(tmp) / "ab")
        start, cpu_start = time.perf_counter(), _cpu_s()
        run(ablation, workers=workers, runner=scripted_episode)
        wall, cpu = time.perf_counter() - start, _cpu_s() - cpu_start
        entries = list(ablation.entries.values())
        errors = [e for e in entries if e.status == "error"]
        if errors:
            raise RuntimeError(f"{len(errors)} episode(s) failed, first: {errors[0].key}: {errors[0].error}")
        return wall, cpu, len(entries), sum(1 for e in entries if e.success)


def main() -> None:
    """Print the throughput table."""
    repeats = int(os.environ.get("BENCH_ABLATE_REPEATS", "1"))
    walls: dict[int, list[float]] = {1: [], 2: []}
    cpus: dict[int, list[float]] = {1: [], 2: []}
    cores: dict[int, list[float]] = {1: [], 2: []}
    size = successes = 0
    for _ in range(repeats):
        for workers in (1, 2):
            cores[workers].append(cores_available(workers))
            wall, cpu, size, successes = _sweep(workers)
            walls[workers].append(wall)
            cpus[workers].append(cpu)
    serial, parallel = statistics.median(walls[1]), statistics.median(walls[2])
    speedup = serial / parallel
    core_ratio = statistics.median(cores[2]) / statistics.median(cores[1])
    projected = parallel / size * PROTOCOL_EPISODES
    # On a machine shared with other work the wall times stretch; the CPU time per episode does not.
    cpu_per_episode = statistics.median(cpus[2]) / size
    projected_idle = cpu_per_episode * PROTOCOL_EPISODES / 2
    load = os.getloadavg()[0]
    print(
        f"\nbench.ablate — {size}-episode factory ablation (stepwise, LiDAR + 640×480 camera, scripted model)"
    )
    print(
        f"(median of {repeats} sweep(s); {successes}/{size} scripted episodes succeeded; load avg {load:.1f};"
        f" CPU pressure {cpu_pressure()} of the last 10 s)"
    )
    header = f"{'workers':>8} {'wall (s)':>9} {'episodes/min':>13} {'CPU/episode (s)':>16}"
    print(f"{header} {'cores used':>11} {'cores free':>11}")
    for workers, wall in ((1, serial), (2, parallel)):
        cpu = statistics.median(cpus[workers]) / size
        free = statistics.median(cores[workers])
        print(
            f"{workers:>8} {wall:>9.1f} {size / wall * 60:>13.1f} {cpu:>16.2f} {cpu * size / wall:>11.2f}"
            f" {free:>11.2f}"
        )
    print(
        "(cores used: CPU time / wall time of the sweep; cores free: CPU that as many busy-looping"
        " processes got just before it)"
    )
    verdict = "ok" if speedup >= TARGET_SPEEDUP else "BELOW TARGET"
    print(f"speed-up 2 vs 1 workers: {speedup:.2f}× (target ≥ {TARGET_SPEEDUP}×) {verdict}")
    # Two workers cannot beat the cores the machine leaves them; this is the share of that bound reached.
    print(
        f"  the free cores allowed {core_ratio:.2f}×; reached {speedup / core_ratio:.0%} of it; "
        f"CPU/episode 2 vs 1 workers {statistics.median(cpus[2]) / statistics.median(cpus[1]):.2f} "
        "(1.00 = the workers do not slow each other down)"
    )
    for label, value in (("measured", projected), ("CPU-bound, 2 idle cores", projected_idle)):
        verdict = "ok" if value <= TARGET_PROTOCOL_S else "ABOVE TARGET"
        print(
            f"projected {PROTOCOL_EPISODES}-episode protocol, 2 workers, {label}: {value / 60:.1f} min "
            f"(target ≤ {TARGET_PROTOCOL_S / 60:.0f} min) {verdict}"
        )


if __name__ == "__main__":
    main()
