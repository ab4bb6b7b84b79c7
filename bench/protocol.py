"""The 200-episode factory protocol as a real sweep: wall time against the 30-minute target.

`python -m bench protocol` runs `llmnav ablate` on the factory with the hybrid planner and the embedded
default model (10 tasks x 5 start poses x 4 trials = 200 episodes, a drive's default decision cap,
sensed information: no map), two workers, and reads the run folders back: wall time, episodes per
minute, decisions per episode, model calls, success. It is not part of `make bench`'s default list
(it takes about a quarter of an hour on 2 cores); name it to run it.

`BENCH_PROTOCOL_OUT=DIR` keeps the ablation folder (a re-run resumes it: then the wall time covers only
what was left, and is said so). `BENCH_PROTOCOL_TRIALS=N` and `BENCH_PROTOCOL_TASKS=T1,T2` run a smaller
grid for a quick look; its time is also shown scaled to 200 episodes. The load average is
printed at the start and the end: the two workers want both cores to themselves. Quick mode
(`main(quick=True)`): T1 from poses 1 and 2, 2 decisions each, the same two workers; no target is
judged, and a sweep in which no episode finished raises.
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from bench import NOT_MEASURED, judged, quick_from_env

TARGET_MIN = 30.0  # [min] the protocol on 2 cores
TRIALS = 4
PROTOCOL_EPISODES = 200  # 10 tasks x 5 start poses x TRIALS
WORKERS = 2
CLI = [sys.executable, "-c", "from llmnav.cli import main; main()"]
QUICK_GRID = ["--tasks", "T1", "--poses", "1,2", "--trials", "1", "-o", "max_iterations=2"]


def _sweep(out: Path, grid: list[str]) -> float:
    """Run (or resume) the sweep of `grid` (ablate flags) into `out`; wall time [s]. Progress goes to stderr."""
    command = [*CLI, "ablate", "--scenario", "factory", "--planner", "hybrid", *grid]
    command += ["--workers", str(WORKERS), "--out", str(out)]
    print(f"[bench.protocol] {' '.join(command[3:])}", flush=True)
    t0 = time.perf_counter()
    subprocess.run(command, check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - t0


def _summaries(out: Path, manifest: dict[str, Any]) -> list[dict[str, Any]]:
    return [
        json.loads((out / row["summary"]).read_text()) for row in manifest["episodes"] if row.get("status") == "done"
    ]


def main(quick: bool = False) -> None:
    """Run the sweep and print its table (quick: 2 short episodes, not a measurement)."""
    trials = int(os.environ.get("BENCH_PROTOCOL_TRIALS", TRIALS))
    tasks = os.environ.get("BENCH_PROTOCOL_TASKS", "all")
    grid = QUICK_GRID if quick else ["--tasks", tasks, "--poses", "all", "--trials", str(trials)]
    kept = None if quick else os.environ.get("BENCH_PROTOCOL_OUT")
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(kept) if kept else Path(tmp) / "protocol"
        resumed = (out / "manifest.json").exists()
        load0 = os.getloadavg()[0]
        wall = _sweep(out, grid)
        load1 = os.getloadavg()[0]
        manifest = json.loads((out / "manifest.json").read_text())
        runs = _summaries(out, manifest)
    if not runs:
        where = f"see {out}/manifest.json" if kept else "set BENCH_PROTOCOL_OUT=DIR to keep the folder"
        message = f"[bench.protocol] no episode finished ({manifest.get('errors', 0)} errors): {where}"
        if quick:  # a check that the sweep still runs: none finished is a failure
            raise RuntimeError(message)
        print(message)
        return
    layout = manifest.get("layout", {})
    decisions = [int(r["iterations"]) for r in runs]
    calls = [int(r["llm_calls"]) for r in runs]
    episode_s = [float(r["wall_time_s"]) for r in runs]
    successes = sum(bool(r["success"]) for r in runs)
    scaled = wall / 60.0 * PROTOCOL_EPISODES / len(runs)  # [min] at the full 200 when fewer ran
    print(
        f"\n[bench.protocol] factory, hybrid (sensed), default backend, {len(runs)} episodes, "
        f"{layout.get('workers')} workers ({layout.get('chosen')} -> model {layout.get('model')}), "
        f"load {load0:.1f} at the start, {load1:.1f} at the end" + (f"; {NOT_MEASURED}" if quick else "")
    )
    note = "  (resumed: only what was left)" if resumed else ""
    print(f"  {'wall time of the sweep':<42} {wall / 60.0:>9.1f} min{note}")
    print(f"  {'episodes per minute':<42} {len(runs) / wall * 60.0:>9.2f}")
    print(f"  {'decisions per episode, mean (max)':<42} {statistics.mean(decisions):>9.2f} ({max(decisions)})")
    print(f"  {'model calls per episode, mean':<42} {statistics.mean(calls):>9.2f}")
    print(f"  {'episode wall time, median':<42} {statistics.median(episode_s):>9.1f} s")
    print(f"  {'success':<42} {successes:>5}/{len(runs)}")
    verdict = judged("ok" if scaled <= TARGET_MIN else "FAIL", quick)
    if resumed:
        verdict = "not judged (resumed)"
    label = "200 episodes (measured, or scaled to 200)"
    print(f"  {label:<42} {scaled:>9.1f} min  target <= {TARGET_MIN:g} min: {verdict}")


if __name__ == "__main__":
    main(quick=quick_from_env())
