"""Generated buildings: every baseline and answer policy on flats nobody tuned to, against the issue's targets.

`python -m bench buildings` generates flats of seeds 0..N-1 (`llmnav scenarios generate`; N = 100, or
`BENCH_BUILDINGS=N`), draws 3 of each flat's target tasks with a start pose each (a `random.Random` seeded
with the flat's seed: fixed, whatever else runs), and drives every episode under each condition, all with
`sensed` information (LiDAR, camera and odometry; the baselines keep their true map, only their pose is
sensed):

- `oracle`: the oracle planner (the shortest path on the true map, driven on its localized pose);
- `frontier`: frontier exploration, then the shortest path to what it detected;
- `hybrid · oracle answers`: the hybrid planner with every answer right (`policy:oracle`);
- `hybrid · local model`: the hybrid planner with the embedded default model (`local`);
- `hybrid · policy:first|keyword|random`: the null policies.

It prints success, collisions (total, and episodes with any), SPL, the final pose error (median and max
over the condition's episodes) and the failure causes, then the issue's targets beside the measured values
with their ratio (measured / target: ≥ 1 meets a success target, ≤ 1 an error or collision bound).
Then, unless `BENCH_BUILDINGS_SWEEP=0`, the timing of a generated sweep (hybrid, local model, 2 workers;
`BENCH_BUILDINGS_SWEEP` episodes, default 300) — measured on the episodes asked for and, when fewer than
300, extrapolated to 300 (said so). When the table's local-model row itself ran on 2 workers into a fresh
folder, its wall time is that measurement, reported without driving the episodes twice.

`BENCH_BUILDINGS_CONDITIONS=oracle,frontier,...` (the keys of CONDITIONS) runs some; `BENCH_BUILDINGS_WORKERS`
(default 1) runs the table's episodes in that many processes; `BENCH_BUILDINGS_OUT=DIR` keeps every run
folder, and a later run with the same folder reads finished episodes back instead of driving them again.
The load average is printed with every timing: the machine may be shared.
Quick mode: 1 flat, 1 task, every condition at most 2 decisions; no target is judged.
"""

from __future__ import annotations

import json
import multiprocessing
import os
import random
import statistics
import tempfile
import time
from collections import Counter
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bench import NOT_MEASURED, judged, quick_from_env
from llmnav.ablate.executors import init_worker, worker_model_threads
from llmnav.buildings.suite import suite_files
from llmnav.planners.base import drive_options
from llmnav.runs.runner import EpisodeSpec, run_episode
from llmnav.world.scenario import load_scenario

BUILDINGS = 100
TASKS_PER_BUILDING = 3
KIND = "flat"
SWEEP_EPISODES = 300  # the generated sweep
SWEEP_TARGET_MIN = 30.0  # [min] on 2 idle cores
SWEEP_WORKERS = 2
POSE_MEDIAN_TARGET_M = 0.10  # [m] final pose error, median over the episodes
POSE_MAX_TARGET_M = 0.30  # [m] and max


@dataclass(frozen=True)
class Condition:
    """One row of the table: a planner, its answers (None: no model) and its success target, if any."""

    label: str
    planner: str
    backend: str | None
    success_target: float | None  # [share] the floor


CONDITIONS: dict[str, Condition] = {
    "oracle": Condition("oracle planner", "oracle", None, 0.99),
    "frontier": Condition("frontier baseline", "frontier", None, 0.85),
    "hybrid-oracle": Condition("hybrid · oracle answers", "hybrid", "policy:oracle", 0.90),
    "hybrid-local": Condition("hybrid · local model", "hybrid", "local", None),
    "first": Condition("hybrid · policy:first", "hybrid", "policy:first", None),
    "keyword": Condition("hybrid · policy:keyword", "hybrid", "policy:keyword", None),
    "random": Condition("hybrid · policy:random", "hybrid", "policy:random", None),
}


@dataclass(frozen=True)
class Episode:
    """One generated flat's task from one start pose."""

    scenario: Path
    task_id: str
    start_pose: int  # 1-based

    @property
    def name(self) -> str:
        """Its run folder's name."""
        return f"{self.scenario.stem}-{self.task_id}-p{self.start_pose}"


def episodes(files: list[Path], per_building: int) -> list[Episode]:
    """`per_building` target tasks of each flat and a start pose each, drawn with the flat's own seed."""
    chosen: list[Episode] = []
    for path in files:
        scenario = load_scenario(str(path))
        seed = int(path.stem.rsplit("-", 1)[-1])
        rng = random.Random(f"bench.buildings {seed}")
        targeted = [t for t in scenario.tasks if t.targets]
        for task in rng.sample(targeted, min(per_building, len(targeted))):
            pose = rng.randint(1, len(scenario.start_poses(task)))
            chosen.append(Episode(path, task.id, pose))
    return chosen


def _drive(job: tuple[Episode, Condition, Path, dict[str, Any]]) -> dict[str, Any]:
    """One episode's summary; read back when its folder already holds one (a resumed run)."""
    episode, condition, out, options = job
    done = out / "summary.json"
    if done.exists():
        return dict(json.loads(done.read_text()))
    spec = EpisodeSpec(
        scenario=str(episode.scenario),
        task_id=episode.task_id,
        start_pose=episode.start_pose,
        backend=condition.backend or "local",
        options=drive_options(planner=condition.planner, information="sensed", seed=0, **options),
        out_dir=out,
        plots=False,
    )
    return run_episode(spec)


def run_condition(
    condition: Condition, chosen: list[Episode], root: Path, workers: int, options: dict[str, Any]
) -> tuple[list[dict[str, Any]], float]:
    """The summaries of every episode under `condition`, and the wall time [s] they took."""
    jobs = [(e, condition, root / e.name, options) for e in chosen]
    start = time.perf_counter()
    if workers <= 1:
        summaries = [_drive(job) for job in jobs]
    else:
        # Each worker's model gets the pool's share of the cores, as in `llmnav ablate`: left to choose by
        # the load at start-up, two idle-born workers took 2 threads each and ran about 20x slower.
        initargs = (worker_model_threads(workers), os.getpid(), {})
        spawn = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(workers, mp_context=spawn, initializer=init_worker, initargs=initargs) as pool:
            summaries = list(pool.map(_drive, jobs))
    return summaries, time.perf_counter() - start


@dataclass(frozen=True)
class Row:
    """What the table shows of one condition."""

    n: int
    successes: int
    collisions: int  # contacts over all episodes
    collided: int  # episodes with any
    spl: float
    pose_median_m: float | None
    pose_max_m: float | None
    causes: Counter[str]

    @classmethod
    def of(cls, summaries: list[dict[str, Any]]) -> Row:
        """Aggregate the summaries of one condition."""
        finals = [s["pose_error_m"]["final"] for s in summaries if s.get("pose_error_m")]
        return cls(
            n=len(summaries),
            successes=sum(bool(s.get("success")) for s in summaries),
            collisions=sum(int(s.get("collisions") or 0) for s in summaries),
            collided=sum(1 for s in summaries if s.get("collisions")),
            spl=statistics.mean(float(s.get("spl") or 0.0) for s in summaries),
            pose_median_m=statistics.median(finals) if finals else None,
            pose_max_m=max(finals) if finals else None,
            causes=Counter(str(s.get("failure_cause")) for s in summaries if not s.get("success")),
        )


def _metres(value: float | None) -> str:
    return "—" if value is None else f"{value:.3f}"


def print_table(rows: dict[str, Row], quick: bool) -> None:
    """The measured table, then each target beside its measured value and the ratio."""
    header = f"{'condition':<26} {'n':>4} {'success':>13} {'collisions':>11} {'SPL':>6}"
    print(f"{header} {'pose err [m] med':>17} {'max':>6}")
    for key, row in rows.items():
        share = f"{row.successes}/{row.n} {row.successes / row.n:.0%}"
        hit = f"{row.collisions} ({row.collided} ep)"
        print(
            f"{CONDITIONS[key].label:<26} {row.n:>4} {share:>13} {hit:>11} {row.spl:>6.3f} "
            f"{_metres(row.pose_median_m):>17} {_metres(row.pose_max_m):>6}"
        )
    print("failure causes:")
    for key, row in rows.items():
        causes = ", ".join(f"{cause} {count}" for cause, count in row.causes.most_common()) or "none"
        print(f"  {CONDITIONS[key].label:<26} {causes}")
    print(f"targets (ratio = measured / target){' — ' + NOT_MEASURED if quick else ''}:")
    for key, row in rows.items():
        label = CONDITIONS[key].label
        target = CONDITIONS[key].success_target
        if target is not None:
            share = row.successes / row.n
            verdict = judged("meets" if share >= target else "MISSES", quick)
            print(f"  {label:<26} success {share:.1%} vs ≥ {target:.0%}: ratio {share / target:.2f}  {verdict}")
        verdict = judged("meets" if row.collisions == 0 else "MISSES", quick)
        print(f"  {label:<26} collisions {row.collisions} vs 0  {verdict}")
        if row.pose_median_m is not None and row.pose_max_m is not None:
            ok = row.pose_median_m <= POSE_MEDIAN_TARGET_M and row.pose_max_m <= POSE_MAX_TARGET_M
            print(
                f"  {label:<26} pose error median {row.pose_median_m:.3f} vs ≤ {POSE_MEDIAN_TARGET_M} m: ratio "
                f"{row.pose_median_m / POSE_MEDIAN_TARGET_M:.2f}; max {row.pose_max_m:.3f} vs ≤ {POSE_MAX_TARGET_M} m: "
                f"ratio {row.pose_max_m / POSE_MAX_TARGET_M:.2f}  {judged('meets' if ok else 'MISSES', quick)}"
            )


@dataclass(frozen=True)
class Timed:
    """A condition's wall time [s] over its episodes, with the 1-minute load average at its start and end."""

    episodes: int
    wall: float  # [s]
    load0: float
    load1: float


def sweep_timing(
    files: list[Path], root: Path, count: int, quick: bool, options: dict[str, Any], done: Timed | None
) -> None:
    """Wall time of `count` hybrid episodes with the local model on 2 workers, extrapolated to 300 if fewer.

    `done` is the table's own local-model row when it already ran those episodes on 2 workers: the same
    measurement, so it is reported instead of driving every episode a second time.
    """
    if done is not None and done.episodes >= count:
        summaries_n, wall, load0, load1 = done.episodes, done.wall, done.load0, done.load1
        print("sweep: the table's local-model row ran on 2 workers; its wall time is the sweep's")
    else:
        chosen = episodes(files, TASKS_PER_BUILDING)[:count]
        load0 = os.getloadavg()[0]
        summaries, wall = run_condition(CONDITIONS["hybrid-local"], chosen, root / "sweep", SWEEP_WORKERS, options)
        load1 = os.getloadavg()[0]
        summaries_n = len(summaries)
    scaled = wall / summaries_n * SWEEP_EPISODES / 60.0  # [min]
    how = "measured" if summaries_n >= SWEEP_EPISODES else f"extrapolated from {summaries_n} episodes"
    verdict = judged("meets" if scaled <= SWEEP_TARGET_MIN else "ABOVE TARGET", quick)
    print(
        f"sweep: hybrid · local model, {SWEEP_WORKERS} workers, {summaries_n} episodes in {wall / 60.0:.1f} min "
        f"(load {load0:.1f} at the start, {load1:.1f} at the end)"
    )
    print(f"  {SWEEP_EPISODES} episodes: {scaled:.1f} min ({how}); target ≤ {SWEEP_TARGET_MIN:g} min  {verdict}")


def main(quick: bool = False) -> None:
    """Generate the flats, run every condition, print the table and the sweep timing."""
    count = 1 if quick else int(os.environ.get("BENCH_BUILDINGS", BUILDINGS))
    per_building = 1 if quick else TASKS_PER_BUILDING
    keys = os.environ.get("BENCH_BUILDINGS_CONDITIONS", ",".join(CONDITIONS)).split(",")
    unknown = [k for k in keys if k not in CONDITIONS]
    if unknown:
        raise ValueError(f"BENCH_BUILDINGS_CONDITIONS: unknown {', '.join(unknown)} (known: {', '.join(CONDITIONS)})")
    workers = 1 if quick else int(os.environ.get("BENCH_BUILDINGS_WORKERS", "1"))
    sweep = 2 if quick else int(os.environ.get("BENCH_BUILDINGS_SWEEP", SWEEP_EPISODES))
    options: dict[str, Any] = {"max_iterations": 2} if quick else {}
    kept = None if quick else os.environ.get("BENCH_BUILDINGS_OUT")
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(kept) if kept else Path(tmp)
        files = suite_files(f"generated:{KIND}:{count}", root / "scenarios")
        chosen = episodes(files, per_building)
        mode = f"; {NOT_MEASURED}" if quick else ""
        print(
            f"bench.buildings: {len(files)} generated {KIND}s (seeds 0-{count - 1}) x {per_building} task(s) = "
            f"{len(chosen)} episodes a condition, sensed information, {workers} worker(s){mode}"
        )
        rows: dict[str, Row] = {}
        local: Timed | None = None
        for key in keys:
            load = os.getloadavg()[0]
            summaries, wall = run_condition(CONDITIONS[key], chosen, root / key, workers, options)
            rows[key] = Row.of(summaries)
            if key == "hybrid-local" and workers == SWEEP_WORKERS and not kept:
                local = Timed(len(summaries), wall, load, os.getloadavg()[0])
            print(
                f"  [{CONDITIONS[key].label}] {len(summaries)} episodes in {wall / 60.0:.1f} min "
                f"(load {load:.1f} at the start)",
                flush=True,
            )
        print_table(rows, quick)
        if sweep > 0:
            sweep_timing(files, root, sweep, quick, options, local)


if __name__ == "__main__":
    main(quick=quick_from_env())
