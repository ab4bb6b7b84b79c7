"""Ablation throughput: a sim-bound sweep on 1 and 2 workers, and the model layouts of a model-bound one.

1. Sim-bound: 40 factory episodes (stepwise planner with LiDAR + 640×480 camera, LiDAR sectors 3 vs 8 ×
   all 10 tasks × start poses 1–2, at most 12 decisions) answered by `policy:first`, which answers at
   once with no model, through the real episode runner: the cost is llmnav's own (simulation, sensors,
   prompts, guard, logs, summaries, the process pool). Targets: 2 workers ≥ 1.8× the episodes/min of 1,
   and the full factory protocol (200 episodes) projected ≤ 5 min with 2 workers.
2. Model-bound: 4 factory episodes (hybrid planner, embedded SmolLM2-135M, T1 and T5 from poses 1–2, at
   most 6 decisions) on 2 workers, with a copy of the model in each worker and with one shared model
   server (`llmnav.ablate.layout`); the run logs of the two layouts are compared, timing fields aside.

The machine is shared: every table carries the load average, and the sim-bound one the cores that as
many busy processes got just before each sweep (two workers cannot beat the cores they are left).
BENCH_ABLATE_REPEATS (default 1) takes medians over several sweeps; BENCH_ABLATE_MODEL=0 skips part 2.
Quick mode: 2 episodes of at most 2 decisions (1 with the model) in each sweep; no target is judged.
"""

from __future__ import annotations

import json
import os
import resource
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

from bench import NOT_MEASURED, judged, quick_from_env
from llmnav.ablate import grid_from_mapping, plan, run
from llmnav.ablate import layout as layouts

TARGET_SPEEDUP = 1.8
TARGET_PROTOCOL_S = 300.0  # [s] 200 episodes with 2 workers
PROTOCOL_EPISODES = 200
SIM_GRID: dict[str, Any] = {
    "scenario": "factory",
    "tasks": "all",
    "poses": [1, 2],
    "trials": 1,
    "lidar_sectors": [3, 8],
    "planner": ["stepwise"],
    "backend": ["policy:first"],
    "sensing": ["lidar+image"],
    "options": {"max_iterations": 12, "max_vetoes": 5},
}
MODEL_GRID: dict[str, Any] = {
    "scenario": "factory",
    "tasks": ["T1", "T5"],
    "poses": [1, 2],
    "planner": ["hybrid"],
    "backend": ["local"],
    "options": {"max_iterations": 6},
}
# Quick mode: two short episodes a sweep, the same factors otherwise.
QUICK_SIM_GRID: dict[str, Any] = {
    **SIM_GRID,
    "tasks": ["T1", "T2"],
    "poses": [1],
    "lidar_sectors": [3],
    "options": {**SIM_GRID["options"], "max_iterations": 2},
}
QUICK_MODEL_GRID: dict[str, Any] = {**MODEL_GRID, "tasks": ["T1"], "options": {"max_iterations": 1}}
QUICK_SPIN_S = 0.2  # [s] of busy loop that measures the free cores (2 s in full)
# Fields of a run log that measure time, not behaviour (and the prompt cache's state, which depends on
# what the same process answered before).
_TIMING = frozenset(
    {"t_wall", "latency_s", "wall_time_s", "prompt_ms", "generation_ms", "tokens_per_s", "cached_tokens",
     "new_prompt_tokens"}
)  # fmt: skip


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


def _sweep(grid: dict[str, Any], root: Path, workers: int, layout: str = "auto") -> tuple[float, float, int, int]:
    """Wall time [s], CPU time [s], episodes and successes of one sweep of `grid` into the new folder `root`."""
    ablation = plan(grid_from_mapping(grid, "bench"), root)
    start, cpu_start = time.perf_counter(), _cpu_s()
    run(ablation, workers=workers, layout=layout)
    wall, cpu = time.perf_counter() - start, _cpu_s() - cpu_start
    entries = list(ablation.entries.values())
    errors = [e for e in entries if e.status == "error"]
    if errors:
        raise RuntimeError(f"{len(errors)} episode(s) failed, first: {errors[0].key}: {errors[0].error}")
    return wall, cpu, len(entries), sum(1 for e in entries if e.success)


def _behaviour(run_dir: Path) -> list[Any]:
    """A run log without its timing fields: what the episode did and what the model answered."""

    def strip(value: Any) -> Any:
        if isinstance(value, dict):
            return {k: strip(v) for k, v in value.items() if k not in _TIMING}
        if isinstance(value, list):
            return [strip(v) for v in value]
        return value

    return [strip(json.loads(line)) for line in (run_dir / "run.jsonl").read_text().splitlines()]


def sim_bound(repeats: int, quick: bool = False) -> None:
    """Print the sim-bound table: episodes/min at 1 and 2 workers and their ratio."""
    grid, spin_s = (QUICK_SIM_GRID, QUICK_SPIN_S) if quick else (SIM_GRID, 2.0)
    walls: dict[int, list[float]] = {1: [], 2: []}
    cpus: dict[int, list[float]] = {1: [], 2: []}
    cores: dict[int, list[float]] = {1: [], 2: []}
    loads: list[float] = []
    size = successes = 0
    for _ in range(repeats):
        for workers in (1, 2):
            cores[workers].append(cores_available(workers, spin_s))
            loads.append(os.getloadavg()[0])
            with tempfile.TemporaryDirectory() as tmp:
                wall, cpu, size, successes = _sweep(grid, Path(tmp) / "ab", workers)
            walls[workers].append(wall)
            cpus[workers].append(cpu)
    loads.append(os.getloadavg()[0])
    serial, parallel = statistics.median(walls[1]), statistics.median(walls[2])
    speedup = serial / parallel
    core_ratio = statistics.median(cores[2]) / statistics.median(cores[1])
    print(f"\nbench.ablate — sim-bound: {size} factory episodes (stepwise, LiDAR + 640×480 camera, policy:first)")
    print(
        f"(median of {repeats} sweep(s) each; {successes}/{size} succeeded; load avg {min(loads):.1f}–{max(loads):.1f};"
        f" CPU pressure {cpu_pressure()} of the last 10 s)" + (f"; {NOT_MEASURED}" if quick else "")
    )
    header = f"{'workers':>8} {'wall (s)':>9} {'episodes/min':>13} {'CPU/episode (s)':>16}"
    print(f"{header} {'cores used':>11} {'cores free':>11}")
    for workers, wall in ((1, serial), (2, parallel)):
        cpu = statistics.median(cpus[workers]) / size
        free = statistics.median(cores[workers])
        print(
            f"{workers:>8} {wall:>9.1f} {size / wall * 60:>13.1f} {cpu:>16.2f} {cpu * size / wall:>11.2f} {free:>11.2f}"
        )
    print("(cores used: CPU time / wall time; cores free: CPU that as many busy-looping processes got just before)")
    verdict = judged("ok" if speedup >= TARGET_SPEEDUP else "BELOW TARGET", quick)
    print(f"speed-up 2 vs 1 workers: {speedup:.2f}× (target ≥ {TARGET_SPEEDUP}×) {verdict}")
    # Two workers cannot beat the cores the machine leaves them; this is the share of that bound reached.
    cpu_ratio = statistics.median(cpus[2]) / statistics.median(cpus[1])
    print(
        f"  the free cores allowed {core_ratio:.2f}×; reached {speedup / core_ratio:.0%} of it; "
        f"CPU/episode 2 vs 1 workers {cpu_ratio:.2f} (1.00 = the workers do not slow each other down)"
    )
    projected = parallel / size * PROTOCOL_EPISODES
    projected_idle = statistics.median(cpus[2]) / size * PROTOCOL_EPISODES / 2
    for label, value in (("measured", projected), ("CPU-bound, 2 idle cores", projected_idle)):
        verdict = judged("ok" if value <= TARGET_PROTOCOL_S else "ABOVE TARGET", quick)
        print(
            f"projected {PROTOCOL_EPISODES}-episode protocol, 2 workers, {label}: {value / 60:.1f} min "
            f"(target ≤ {TARGET_PROTOCOL_S / 60:.0f} min) {verdict}"
        )


def model_bound(repeats: int, quick: bool = False) -> None:
    """Print the model-bound table: a model copy per worker against one shared server, 2 workers."""
    grid = QUICK_MODEL_GRID if quick else MODEL_GRID
    cap = grid["options"]["max_iterations"]
    rates: dict[str, list[float]] = {"per-worker": [], "shared": []}
    loads: list[float] = []
    same = compared = 0
    size = 0
    for _ in range(repeats):
        with tempfile.TemporaryDirectory() as tmp:
            for layout in rates:
                loads.append(os.getloadavg()[0])
                wall, _, size, _ = _sweep(grid, Path(tmp) / layout, 2, layout)
                rates[layout].append(size / wall * 60)
            loads.append(os.getloadavg()[0])
            for folder in sorted(p for p in (Path(tmp) / "shared").iterdir() if p.is_dir()):
                compared += 1
                same += _behaviour(folder) == _behaviour(Path(tmp) / "per-worker" / folder.name)
    per_worker, shared = statistics.median(rates["per-worker"]), statistics.median(rates["shared"])
    print(
        f"\nbench.ablate — model-bound: {size} factory episodes (hybrid, embedded model, ≤ {cap} decisions), 2 workers"
    )
    mode = f"; {NOT_MEASURED}" if quick else ""
    print(f"(median of {repeats} sweep(s) each; load avg {min(loads):.1f}–{max(loads):.1f}{mode})")
    print(f"{'layout':>12} {'episodes/min':>13}")
    print(f"{'per-worker':>12} {per_worker:>13.2f}   (a copy of the model in each worker)")
    print(f"{'shared':>12} {shared:>13.2f}   (one server, a slot per worker, on 127.0.0.1)")
    print(f"shared vs per-worker: {shared / per_worker:.2f}×; run logs identical in {same}/{compared} episodes")
    recorded = ", ".join(f"{name} {rate:.2f}" for name, rate in layouts.MEASURED.items())
    print(f"`ablate --model-layout auto` takes: {layouts.faster()} (recorded episodes/min: {recorded})")


def main(quick: bool = False) -> None:
    """Print both tables (quick: one sweep of 2 short episodes each, not a measurement)."""
    repeats = 1 if quick else int(os.environ.get("BENCH_ABLATE_REPEATS", "1"))
    sim_bound(repeats, quick)
    if os.environ.get("BENCH_ABLATE_MODEL", "1") != "0":
        model_bound(repeats, quick)


if __name__ == "__main__":
    main(quick=quick_from_env())
