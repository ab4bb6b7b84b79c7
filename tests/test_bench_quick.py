"""Every benchmark's quick mode runs in the default suite: a change that breaks a benchmark fails here.

Each module runs as `python -m bench --quick NAME` in its own process (from the repository root, where
`make bench` runs it); the test reads its table back: the rows it must print, each with a number, and
the note that quick numbers judge no target.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
NUMBER = r"-?\d+(?:\.\d+)?"
NOT_MEASURED = "quick: not a measurement"

# Per module: (label, pattern) of rows its table must hold. A pattern is matched from the start of a line.
ROWS: dict[str, list[str]] = {
    "sim": [
        rf"\s+physics step, idle robot\s+{NUMBER}\s+{NUMBER} ms",
        rf"\s+LiDAR scan \(\d+ rays\)\s+{NUMBER}",
        rf"\s+decision step: 1 m move \+ LiDAR\s+{NUMBER}",
        rf"\s+hybrid sensed factory T1 \(policy:first\)\s+{NUMBER}\s+{NUMBER} ms\s+per decision \(\d+\)",
        rf"\s+stepwise factory T1 \(policy:first\)\s+{NUMBER}",
        rf"\s+waypoints corridor_a \(policy:keyword\)\s+{NUMBER}",
        rf"\s+FSM maze_arena M1 \(no assist\)\s+{NUMBER}",
        rf"\s+process start -> first model request\s+{NUMBER}",
        rf"\s+ablate oracle, 2 episodes, 2 worker\(s\)\s+{NUMBER}",
    ],
    "guard": [
        rf"\s+valid plain\s+\d+\s+{NUMBER}\s+{NUMBER}\s+ok",
        rf"\s+all\s+100\s+{NUMBER}",
        rf"\s+veto check \(360 rays\) median {NUMBER} ms",
        rf"\s+velocity tick over 50 ticks: raw {NUMBER} ms, guarded {NUMBER} ms",
    ],
    "local": [
        # each planner made model calls (a planner that never asks prints "no model calls")
        r"\s+stepwise \(lidar\): \d+ calls in 1 episode",
        r"\s+hybrid \(score\): \d+ calls in 1 episode",
        r"\s+hybrid \(generate\): \d+ calls in 1 episode",
        r"\s+fsm \+ llm: \d+ calls in 1 episode",
        rf"\s+warm decision p50 \[s\]\s+{NUMBER}",
        rf"\s+suggestion latency p95 \[ms\]\s+{NUMBER}",
        rf"\s+200 factory episodes of \d+ decisions \[min\]\s+{NUMBER}",
        rf"\s+hybrid on flats, explore=utility: decision p50 \[s\]\s+{NUMBER}",
        rf"\s+hybrid on flats, explore=scored: decision p50 \[s\]\s+{NUMBER}",
        rf"\s+difference of the two p50s \[s\] \(routes differ\)\s+[+-]?{NUMBER}",
        rf"\s+scoring frontiers(, p50 \[s\] a decision that does\s+{NUMBER}|: no decision after the first scored any)",
    ],
    "decision": [
        rf"lidar\s+{NUMBER}\s+{NUMBER}\s+{NUMBER}\s+{NUMBER}\s+{NUMBER}",
        rf"lidar \+ camera 640x480\s+{NUMBER}\s+{NUMBER}",
    ],
    "ablate": [
        r"bench\.ablate — sim-bound: 2 factory episodes",
        rf"\s+1\s+{NUMBER}\s+{NUMBER}\s+{NUMBER}",
        rf"\s+2\s+{NUMBER}\s+{NUMBER}\s+{NUMBER}",
        r"bench\.ablate — model-bound: 2 factory episodes",
        rf"\s+per-worker\s+{NUMBER}",
        rf"\s+shared\s+{NUMBER}",
        r"shared vs per-worker: .*run logs identical in \d+/2 episodes",
    ],
    "calibrate": [
        rf"\s+FSM-only\s+{NUMBER} ± \S+ \(n=\d\)",
        rf"\s+FSM \+ EMA\s+{NUMBER} ± \S+ \(n=\d\)",
    ],
    "information": [
        rf"\s+oracle\s+{NUMBER} s/episode\s+{NUMBER} s/decision",
        rf"\s+sensed\s+{NUMBER} s/episode\s+{NUMBER} s/decision",
        rf"\s+sensed / oracle = {NUMBER} per episode",
    ],
    "localize": [
        r"localize: \d+ scans matched in 1 factory episodes",
        rf"\s+CPU per scan \[ms\]\s+median {NUMBER}\s+p95 {NUMBER}\s+max {NUMBER}",
        rf"\s+pose error at the end \[m\]\s+median {NUMBER}\s+max {NUMBER}",
    ],
    "buildings": [
        r"bench\.buildings: 1 generated flats \(seeds 0-0\) x 1 task\(s\) = 1 episodes a condition, sensed",
        *(
            rf"{label}\s+1\s+\d/1 {NUMBER}%\s+\d+ \(\d ep\)\s+{NUMBER}\s+{NUMBER}\s+{NUMBER}$"
            for label in ("oracle planner", "frontier baseline", "hybrid · oracle answers", "hybrid · local model")
        ),
        *(rf"hybrid · policy:{name}\s+1\s+\d/1" for name in ("first", "keyword", "random")),
        rf"\s+oracle planner\s+success {NUMBER}% vs ≥ 99%: ratio {NUMBER}",
        rf"\s+hybrid · oracle answers\s+pose error median {NUMBER} vs ≤ 0.1 m: ratio {NUMBER}; max {NUMBER}",
        rf"sweep: hybrid · local model, 2 workers, 2 episodes in {NUMBER} min",
        rf"\s+300 episodes: {NUMBER} min \(extrapolated from 2 episodes\)",
    ],
    "rl": [
        r"\s+training steps\s+64$",
        rf"\s+training wall time \[s\]\s+{NUMBER} \(\d+ steps/s\)",
        r"\s+success\s+\d/2 evaluation episodes \(\d+ %\), target 80 %: quick: not a measurement",
        rf"\s+load {NUMBER} at the start, {NUMBER} at the end",
        *(rf"\s+{name}\s+\d+\s+\d+\s+\d+\s+\d+$" for name in ("Factory-v0", "Corridor-v0", "Maze-v0")),
    ],
    "protocol": [
        rf"\s+wall time of the sweep\s+{NUMBER} min",
        rf"\s+episodes per minute\s+{NUMBER}",
        r"\s+decisions per episode, mean \(max\)\s+\d",
        r"\s+success\s+\d+/2",
    ],
}
# Words of a verdict against a target: quick numbers must not be judged.
VERDICTS = re.compile(r"\b(FAIL|MISSES|meets|BELOW TARGET|ABOVE TARGET|OVER)\b")


def run_bench(*args: str, quick_env: bool = False) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
    env.pop("LLMNAV_BENCH_QUICK", None)
    if quick_env:
        env["LLMNAV_BENCH_QUICK"] = "1"
    return subprocess.run(
        [sys.executable, "-m", "bench", *args], cwd=ROOT, env=env, capture_output=True, text=True, timeout=900
    )


@pytest.mark.parametrize("name", list(ROWS))
def test_quick_mode_runs_and_prints_its_table(name):
    result = run_bench("--quick", name)
    assert result.returncode == 0, result.stderr[-3000:]
    missing = [row for row in ROWS[name] if not re.search(row, result.stdout, re.MULTILINE)]
    assert not missing, f"rows missing from bench.{name}:\n{missing}\n--- stdout:\n{result.stdout}"
    assert NOT_MEASURED in result.stdout
    assert not VERDICTS.search(result.stdout), result.stdout


def test_every_module_has_a_quick_test():
    modules = {p.stem for p in (ROOT / "bench").glob("*.py") if not p.stem.startswith("_")}
    assert modules == set(ROWS)


def test_unknown_name_is_one_line_and_exit_2():
    result = run_bench("--quick", "nope")
    assert result.returncode == 2
    assert result.stderr.strip().startswith("unknown benchmark(s) nope")
    assert len(result.stderr.strip().splitlines()) == 1


def test_quick_env_var_asks_for_quick_mode():
    result = run_bench("guard", quick_env=True)
    assert result.returncode == 0, result.stderr[-3000:]
    assert re.search(rf"\s+all\s+100\s+{NUMBER}", result.stdout, re.MULTILINE), result.stdout
    assert NOT_MEASURED in result.stdout


def test_a_failing_module_is_reported_and_the_others_still_run(monkeypatch, capsys):
    monkeypatch.syspath_prepend(str(ROOT))
    import bench.decision
    import bench.guard
    from bench.__main__ import main

    def broken(quick: bool = False) -> None:
        raise AttributeError("an API the benchmark uses is gone")

    ran: list[bool] = []
    monkeypatch.setattr(bench.guard, "main", broken)
    monkeypatch.setattr(bench.decision, "main", lambda quick=False: ran.append(quick))
    assert main(["--quick", "guard", "decision"]) == 1
    assert ran == [True]
    err = capsys.readouterr().err
    assert "AttributeError: an API the benchmark uses is gone" in err
    assert "benchmarks that failed: guard" in err
