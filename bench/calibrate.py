"""Sensing calibration: FSM-only and FSM + EMA on `maze_arena` against the FSM source's published baseline.

The maze's detector and odometry defaults (scenarios/maze_arena.yaml, docs/sensing.md) are chosen so that
the unchanged FSM reproduces the source's stop error. This benchmark runs task M1 from start pose 1 over
seeds 0..N-1 (the seed draws the detector's and the odometry's errors) and prints, per condition, e_pos at
the stop event and the trajectory efficiency eta as mean ± SD (n), the published values, the ratio
ours/published, and Welch's t against the published summary (N = 60). Episodes that do not reach the stop
sign have no e_pos; they are counted and reported.

Set BENCH_CALIBRATE_SEEDS (default 30) and BENCH_CALIBRATE_WORKERS (default 2, processes). Quick mode
runs seed 0 only and judges nothing.
"""

from __future__ import annotations

import os
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bench import NOT_MEASURED, quick_from_env
from llmnav.planners.base import drive_options
from llmnav.runs.runner import EpisodeSpec, run_episode
from llmnav.scoring.stats import mean_sd, welch_summary

SCENARIO, TASK, START_POSE = "maze_arena", "M1", 1
PUBLISHED_N = 60  # runs per condition in the FSM source
QUICK_SEEDS = 1  # an FSM episode to the stop sign costs ~8 s of CPU


@dataclass(frozen=True)
class Published:
    """One condition of the FSM source's results table: e_pos [m] mean ± SD and mean eta."""

    e_pos_mean: float
    e_pos_sd: float
    eta: float


# The FSM source's FSM-only and FSM + EMA rows (mean ± SD over 60 runs; eta reported as a mean only).
PUBLISHED = {"none": Published(0.246, 0.078, 0.821), "ema": Published(0.212, 0.05, 0.855)}
LABELS = {"none": "FSM-only", "ema": "FSM + EMA"}


def episode(args: tuple[str, int, str]) -> tuple[str, int, str, float | None, float | None]:
    """One FSM episode: (assist, seed, outcome, e_pos [m], eta)."""
    assist, seed, out_dir = args
    spec = EpisodeSpec(
        scenario=SCENARIO,
        task_id=TASK,
        start_pose=START_POSE,
        options=drive_options(planner="fsm", assist=assist, seed=seed),  # type: ignore[arg-type]
        backend="local",  # never created: FSM-only and EMA talk to no model
        out_dir=Path(out_dir) / f"{assist}-{seed}",
    )
    summary = run_episode(spec)
    metrics = summary.get("planner_metrics") or {}
    completed = summary["outcome"] == "completed"
    outcome = f"{summary['outcome']} ({summary.get('reason', '')})"
    return (assist, seed, outcome, metrics.get("e_pos_m") if completed else None, metrics.get("eta"))


def _fmt(mean: float, sd: float, n: int) -> str:
    return f"{mean:.3f} ± {sd:.3f} (n={n})"


def run(seeds: int, workers: int) -> dict[str, list[tuple[str, int, str, float | None, float | None]]]:
    """Every episode of both conditions, grouped by assist mode."""
    with tempfile.TemporaryDirectory(prefix="llmnav-calibrate-") as tmp:
        jobs = [(assist, seed, tmp) for assist in PUBLISHED for seed in range(seeds)]
        if workers > 1:
            with ProcessPoolExecutor(max_workers=workers) as pool:
                results = list(pool.map(episode, jobs))
        else:
            results = [episode(job) for job in jobs]
    return {assist: [r for r in results if r[0] == assist] for assist in PUBLISHED}


def report(results: dict[str, list[Any]], quick: bool = False) -> list[str]:
    """The table and the verdict lines (also returned, for tests and logs); quick: the table only."""
    lines = [
        f"{'condition':<11} {'e_pos [m] ours':<24} {'published':<16} {'ratio':>6} {'Welch t':>8}   "
        f"{'eta ours':<24} {'published':>9} {'ratio':>6}"
    ]
    verdicts: list[str] = []
    means: dict[str, float] = {}
    for assist, published in PUBLISHED.items():
        rows = results[assist]
        e_mean, e_sd, e_n = mean_sd([r[3] for r in rows])
        h_mean, h_sd, h_n = mean_sd([r[4] for r in rows if r[3] is not None])
        means[assist] = e_mean
        welch = welch_summary(e_mean, e_sd, e_n, published.e_pos_mean, published.e_pos_sd, PUBLISHED_N)
        lines.append(
            f"{LABELS[assist]:<11} {_fmt(e_mean, e_sd, e_n):<24} {published.e_pos_mean:.3f} ± {published.e_pos_sd:.3f}"
            f"    {e_mean / published.e_pos_mean:>6.2f} {welch.t:>8.2f}   {_fmt(h_mean, h_sd, h_n):<24} "
            f"{published.eta:>9.3f} {h_mean / published.eta:>6.2f}"
        )
        failed = [f"seed {r[1]}: {r[2]}" for r in rows if r[3] is None]
        if failed:
            verdicts.append(
                f"{LABELS[assist]}: {len(failed)} of {len(rows)} episodes without a stop event ({'; '.join(failed)})"
            )
        within = abs(e_mean - published.e_pos_mean) <= published.e_pos_sd
        verdicts.append(
            f"{LABELS[assist]}: e_pos mean {'within' if within else 'OUTSIDE'} the published SD "
            f"(|{e_mean:.3f} - {published.e_pos_mean:.3f}| = {abs(e_mean - published.e_pos_mean):.3f} m "
            f"vs {published.e_pos_sd:.3f} m); SD ratio {e_sd / published.e_pos_sd:.2f}; "
            f"eta {h_mean:.3f} vs {published.eta:.3f} ({h_mean - published.eta:+.3f})"
        )
    # Paired by seed: the same seed draws the same sensor errors until the two runs' paths part.
    fsm = {r[1]: r[3] for r in results["none"] if r[3] is not None}
    pairs = [r[3] - fsm[r[1]] for r in results["ema"] if r[3] is not None and r[1] in fsm]
    if len(pairs) >= 2:
        d_mean, d_sd, d_n = mean_sd(pairs)
        lower = sum(1 for d in pairs if d < 0)
        verdicts.append(
            f"EMA - FSM per seed: {d_mean:+.3f} ± {d_sd:.3f} m (n={d_n}); EMA lower on {lower} of {d_n} seeds"
        )
    change = means["ema"] - means["none"]
    published_change = PUBLISHED["ema"].e_pos_mean - PUBLISHED["none"].e_pos_mean
    direction = "the published direction" if change * published_change > 0 else "NOT the published direction"
    verdicts.append(
        f"EMA ablation: e_pos changes by {change:+.3f} m (published {published_change:+.3f} m): {direction}"
    )
    return lines + ([NOT_MEASURED] if quick else verdicts)


def main(quick: bool = False) -> None:
    """Run both conditions and print the calibration table (quick: 1 seed, no verdicts)."""
    seeds = QUICK_SEEDS if quick else int(os.environ.get("BENCH_CALIBRATE_SEEDS", "30"))
    workers = max(1, int(os.environ.get("BENCH_CALIBRATE_WORKERS", "2")))
    load = os.getloadavg()[0]
    started = time.perf_counter()
    results = run(seeds, workers)
    elapsed = time.perf_counter() - started
    print(
        f"[bench.calibrate] {SCENARIO} {TASK} start pose {START_POSE}, seeds 0..{seeds - 1}, {workers} worker(s), "
        f"{elapsed:.0f} s, load {load:.2f}"
    )
    for line in report(results, quick):
        print("  " + line)


if __name__ == "__main__":
    main(quick=quick_from_env())
