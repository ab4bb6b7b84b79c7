"""Guard overhead: parse_answer per answer over a realistic mix, the safety veto per check, and what the
guarded motion layer adds to a 50 Hz velocity tick (kinematic box + time to collision, a scan every 0.1 s)
and the collision monitor to every control step (a physics step of a discrete motion).

Targets: median parse ≤ 1 ms per answer, veto check far below a LiDAR scan (≈ 1.5 ms, docs/sources.md, M),
the layer's cost per velocity tick ≤ 1 ms (a 20 ms slot also holds the detector and the physics), the
monitor's cost per control step ≤ 0.2 ms.
Quick mode: 100 answers, 200 veto checks and 50 ticks; no target is judged.
"""

from __future__ import annotations

import json
import math
import random
import statistics
import time
from collections.abc import Callable

import numpy as np

from bench import judged, quick_from_env
from llmnav.guard.parse import parse_answer
from llmnav.guard.veto import check_motion
from llmnav.planners.stepwise.answers import ActionBounds, StepAction
from llmnav.sim.sensors import LidarScan as Scan

PARSE_TARGET_MS = 1.0
VETO_TARGET_MS = 1.5  # one LiDAR scan's cost: the veto should be small next to it
TICK_TARGET_MS = 1.0  # [ms] the motion layer's share of a 20 ms velocity tick
MONITOR_TARGET_MS = 0.2  # [ms] the collision monitor's share of one control step (issue target)
MONITOR_LEGS = 12
TICKS = 500
ANSWERS = 1000
VETO_CHECKS = 2000
QUICK_SHARE = 10  # quick mode runs a tenth of the answers, veto checks and ticks


class _Sink:
    sim_time = 0.0

    def event(self, kind: str, **fields: object) -> None:
        pass


def _tick_overhead_ms(ticks: int = TICKS) -> tuple[float, float]:
    """Mean wall time [ms] of a raw and of a guarded velocity tick, driving toward a wall 2 m away.

    The mean, not the median: the layer's scan every 0.1 s (one tick in five) is the cost that matters.
    """
    from llmnav.core.geometry import Pose2D
    from llmnav.guard.view import PlannerWorld
    from llmnav.sim.world import World
    from llmnav.world.scenario import parse_scenario

    scenario = parse_scenario(
        {
            "name": "bench",
            "robot": "burger",
            "bounds": {"x": [-1, 4], "y": [-2, 2]},
            "walls": [{"id": "east", "center": [3.0, 0.0], "size": [0.2, 4.0]}],
            "default_start": {"x": 0.0, "y": 0.0},
        },
        "bench",
    )
    with World(scenario) as world:
        view = PlannerWorld(world, _Sink())
        monitor = world.motion.monitor  # the layer installs the collision monitor; "raw" runs without it
        timings: dict[str, list[float]] = {"raw": [], "guarded": []}
        for name, tick in (("raw", world.motion.velocity_tick), ("guarded", view.motion.velocity_tick)):
            world.motion.monitor = None if name == "raw" else monitor
            world.reset(Pose2D(0.8, 0.0, 0.0))
            for _ in range(ticks):
                start = time.perf_counter()
                tick(0.06, 0.1, 0.02)
                timings[name].append(time.perf_counter() - start)
    return statistics.fmean(timings["raw"]) * 1000.0, statistics.fmean(timings["guarded"]) * 1000.0


def _monitor_per_step_ms(legs: int = MONITOR_LEGS) -> tuple[float, float, int]:
    """Mean wall time [ms] of a control step (one physics step) without and with the collision monitor.

    The PR2 in the factory drives legs past shelves, the stairs and into the pallet's aisle (the monitor
    slows it near them and stops it at the pallet), each leg once without the monitor and once with it.
    """
    from llmnav.core.geometry import Pose2D
    from llmnav.guard.view import PlannerWorld
    from llmnav.sim.world import World
    from llmnav.world.scenario import load_scenario

    starts = [Pose2D(-3.05, -9.4, -math.pi / 2), Pose2D(-8.0, -2.0, 0.0), Pose2D(2.0, 1.5, -math.pi / 2)]
    with World(load_scenario("factory")) as world:
        PlannerWorld(world, _Sink())
        monitor = world.motion.monitor
        totals = {"raw": [0.0, 0], "monitored": [0.0, 0]}  # [s, physics steps]
        for i in range(legs):
            for name in ("raw", "monitored"):
                world.motion.monitor = None if name == "raw" else monitor
                world.reset(starts[i % len(starts)])
                begin, steps = time.perf_counter(), world.step_count
                world.motion.drive(1.8)
                totals[name][0] += time.perf_counter() - begin
                totals[name][1] += world.step_count - steps
    raw = totals["raw"][0] / max(1, int(totals["raw"][1])) * 1000.0
    monitored = totals["monitored"][0] / max(1, int(totals["monitored"][1])) * 1000.0
    return raw, monitored, int(totals["monitored"][1])


def _answer(rng: random.Random) -> dict[str, object]:
    command = rng.choice(["FRONT", "BACK", "ROTATE_LEFT", "ROTATE_RIGHT"])
    value = round(rng.uniform(0.3, 3.0), 2) if command in ("FRONT", "BACK") else rng.choice([15, 30, 45, 90])
    return {
        "goal": "Find the pile of pellets near the loading dock",
        "reasoning": "The aisle ahead is clear for a few metres; the pellets were last seen to the left. "
        * rng.randint(1, 3),
        "scene_description": "Shelves on both sides, a forklift parked on the right, open floor ahead.",
        "action": {"command": command, "parameters": value},
    }


LOOKALIKE = "FR\u041eNT"  # Cyrillic O

# Each maker turns an answer dict into text of one kind a model might produce.
MAKERS: dict[str, Callable[[dict[str, object], random.Random], str]] = {
    "valid plain": lambda a, r: json.dumps(a),
    "valid fenced": lambda a, r: "Here is my decision:\n```json\n" + json.dumps(a, indent=2) + "\n```\n",
    "valid in prose": lambda a, r: "I considered the scene {carefully}. " + json.dumps(a) + " Done.",
    "repair: trailing comma": lambda a, r: json.dumps(a)[:-2] + ",}}",
    "repair: truncated": lambda a, r: json.dumps(a)[: -r.randint(1, 2)],
    "repair: single quotes": lambda a, r: json.dumps(a).replace('"', "'"),
    "schema: NaN": lambda a, r: json.dumps({**a, "action": {"command": "FRONT", "parameters": math.nan}}),
    "schema: look-alike": lambda a, r: json.dumps({**a, "action": {"command": LOOKALIKE, "parameters": 1}}),
    "schema: extra key": lambda a, r: json.dumps({**a, "confidence": 0.9}),
    "bounds: huge": lambda a, r: json.dumps({**a, "action": {"command": "FRONT", "parameters": 1e308}}),
    "parse: prose only": lambda a, r: "I will move forward two metres because the path is clear. " * 3,
}
# Realistic weights: mostly valid, a few of each failure.
WEIGHTS = [40, 25, 10, 4, 4, 3, 3, 2, 3, 3, 3]


def _median_ms(samples: list[float]) -> float:
    return statistics.median(samples) * 1000.0


def main(quick: bool = False) -> None:
    """Print the guard table (quick: a tenth of the samples, not a measurement)."""
    share = QUICK_SHARE if quick else 1
    answers, checks, ticks = ANSWERS // share, VETO_CHECKS // share, TICKS // share
    rng = random.Random(0)
    kinds = rng.choices(list(MAKERS), weights=WEIGHTS, k=answers)
    texts = [(kind, MAKERS[kind](_answer(rng), rng)) for kind in kinds]
    bounds = ActionBounds()
    for _, text in texts[:50]:  # warm-up (imports, pydantic caches)
        parse_answer(text, StepAction, bounds=bounds)
    per_kind: dict[str, list[float]] = {}
    outcomes: dict[str, set[str]] = {}
    everything: list[float] = []
    for kind, text in texts:
        start = time.perf_counter()
        result = parse_answer(text, StepAction, bounds=bounds)
        elapsed = time.perf_counter() - start
        everything.append(elapsed)
        per_kind.setdefault(kind, []).append(elapsed)
        outcomes.setdefault(kind, set()).add(result.outcome + ("+repaired" if result.repaired else ""))

    angles = np.linspace(-math.pi, math.pi, 360, endpoint=False)
    ranges = np.where(np.cos(angles) > 0.1, 2.0 / np.maximum(np.cos(angles), 1e-9), np.inf)
    scan = Scan(angles, ranges)
    veto_times: list[float] = []
    for i in range(checks):
        distance = (0.5, 2.5, -1.0)[i % 3]
        start = time.perf_counter()
        check_motion(distance, scan, robot_width_m=0.72)
        veto_times.append(time.perf_counter() - start)

    mode = ", quick: not a measurement" if quick else ""
    print(f"guard: parse_answer over {answers} mixed answers (StepAction + ActionBounds){mode}")
    print(f"  {'kind':<24}{'n':>5}{'median ms':>11}{'max ms':>9}  outcome")
    for kind in MAKERS:
        samples = per_kind.get(kind, [])
        if samples:
            print(
                f"  {kind:<24}{len(samples):>5}{_median_ms(samples):>11.3f}{max(samples) * 1000:>9.2f}  "
                f"{','.join(sorted(outcomes[kind]))}"
            )
    overall = _median_ms(everything)
    p95 = float(np.percentile(everything, 95)) * 1000.0
    veto = _median_ms(veto_times)
    worst = max(everything) * 1000.0
    print(f"  {'all':<24}{len(everything):>5}{overall:>11.3f}{worst:>9.2f}  p95 {p95:.3f} ms")
    ratio = overall / PARSE_TARGET_MS
    print(f"  median parse {overall:.3f} ms vs target {PARSE_TARGET_MS} ms ({judged(f'ratio {ratio:.2f}', quick)})")
    print(
        f"  veto check (360 rays) median {veto:.3f} ms vs target {VETO_TARGET_MS} ms "
        f"({judged(f'ratio {veto / VETO_TARGET_MS:.2f}', quick)})"
    )
    plain, watched, steps = _monitor_per_step_ms(max(3, MONITOR_LEGS // share))
    cost = watched - plain
    print(
        f"  collision monitor over {steps} control steps (PR2, factory legs): {plain:.4f} ms a step without, "
        f"{watched:.4f} ms with; it adds {cost:.4f} ms vs target {MONITOR_TARGET_MS} ms "
        f"({judged(f'ratio {cost / MONITOR_TARGET_MS:.2f}', quick)})"
    )
    raw, guarded = _tick_overhead_ms(ticks)
    extra = guarded - raw
    print(
        f"  velocity tick over {ticks} ticks: raw {raw:.3f} ms, guarded {guarded:.3f} ms mean; the layer adds "
        f"{extra:.3f} ms vs target {TICK_TARGET_MS} ms ({judged(f'ratio {extra / TICK_TARGET_MS:.2f}', quick)})"
    )


if __name__ == "__main__":
    main(quick=quick_from_env())
