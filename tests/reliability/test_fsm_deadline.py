"""FSM deadline: the 50 Hz controller in realtime mode never misses its 20 ms slot and keeps its own tick
latency (tick start → command published) at p99 ≤ 0.5 ms while a model generates in a worker thread.

Quick subset (default suite): a scripted backend that sleeps 0.2 s per suggestion (the source's ≈ 5 Hz
model) for a short run; it asserts that no tick comes near a 20 ms slot. The p99 bound is a speed target,
checked by `make reliability` (marked slow) over a longer run. The load it adds is one worker thread
that sleeps (no CPU) beside the simulation on one core; what the p99 test asserts is the controller's
own work — every tick within P99_LIMIT_MS at p99 and none near a 20 ms slot — because missed slots
also count the detector and physics, which other processes on a loaded machine can delay (misses and
the load average are recorded in the reliability table).
Full run, on a busy machine: the real local model answering the FSM's state JSON from a process of its
own (as `--realtime` runs an in-process engine), a second copy of the model generating all the time in
another process, and HOG_PROCESSES spinning processes started by the test; the ticks start once the
1-minute load average is ≥ HOG_LOAD and run for ≥ 10 000 ticks on maze_arena (≈ 200 s wall). It asserts
0 missed deadlines (a tick starting more than one 20 ms slot late, `FsmPlanner._pace`).
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, ClassVar

import pytest

import llmnav
from llmnav.backends.base import Backend, ChatRequest, ChatResult
from llmnav.planners.base import drive_options
from llmnav.runs.runlog import read_run
from llmnav.runs.runner import EpisodeSpec, run_episode

CATEGORY = "fsm deadline"
P99_LIMIT_MS = 0.5  # [ms]
HOG_LOAD = 4.0  # the 1-minute load average the full run starts at and keeps
HOG_PROCESSES = 4  # spinning processes the full run starts (the model generating beside them adds one)
HOG_WAIT_S = 240.0  # [s] the load average follows a new load with a 1-minute time constant


class SlowModel(Backend):
    """A model that takes `delay_s` per answer and always suggests a gentle forward speed."""

    name: ClassVar[str] = "slow"

    def __init__(self, delay_s: float) -> None:
        super().__init__("scripted")
        self.delay_s = delay_s
        self.calls = 0

    def chat(self, request: ChatRequest) -> ChatResult:
        self.calls += 1
        time.sleep(self.delay_s)
        return ChatResult("[50,0]", self.delay_s, "slow")


@pytest.fixture
def perception_ms(monkeypatch: pytest.MonkeyPatch) -> list[float]:
    """Wall time [ms] of every detector call: simulated perception runs inline in the 50 Hz loop (outside
    the controller's tick latency but inside its 20 ms slot), so it explains late ticks."""
    from llmnav.sim.sensors import Detector

    spent: list[float] = []
    real = Detector.detect

    def timed(self: Any, *args: Any, **kwargs: Any) -> Any:
        started = time.perf_counter()
        try:
            return real(self, *args, **kwargs)
        finally:
            spent.append((time.perf_counter() - started) * 1000.0)

    monkeypatch.setattr(Detector, "detect", timed)
    return spent


def note_environment(tally: Any, perception: list[float]) -> str:
    import os

    import numpy as np

    load = os.getloadavg()[0]
    p50, p99 = np.percentile(perception, [50, 99]) if perception else (0.0, 0.0)
    tally.note(CATEGORY, "detector p50/p99/max [ms]", f"{p50:.1f}/{p99:.1f}/{max(perception or [0]):.1f}")
    tally.note(CATEGORY, "load avg (1 min)", round(load, 2))
    return f"detector p50 {p50:.1f} ms, p99 {p99:.1f} ms, max {max(perception or [0]):.1f} ms; load {load:.2f}"


def realtime_episode(
    tmp_path: Path, name: str, ticks: int, backend: Backend, view: Any = None
) -> dict[str, Any]:
    spec = EpisodeSpec(
        scenario="maze_arena",
        task_id="M1",
        options=drive_options(planner="fsm", assist="llm", realtime=True, max_ticks=ticks),
        backend=backend.spec,
        out_dir=tmp_path / name,
    )
    summary = run_episode(spec, backend_obj=backend, view=view)
    metrics = read_run(tmp_path / name).of_type("end")[-1]["metrics"]
    assert not str(summary["reason"]).startswith("crash"), summary["reason"]
    return metrics


def record(tally: Any, runs: list[dict[str, Any]]) -> tuple[int, int, float]:
    ticks = sum(m["ticks"] for m in runs)
    missed = sum(m["missed_deadlines"] for m in runs)
    p99 = max(m["tick_latency_ms"]["p99"] for m in runs)
    tally.add(CATEGORY, tried=ticks)
    tally.note(CATEGORY, "ticks", tally.notes.get(CATEGORY, {}).get("ticks", 0) + ticks)
    tally.note(CATEGORY, "missed deadlines", missed)
    tally.note(CATEGORY, "tick p50 [ms]", max(m["tick_latency_ms"]["p50"] for m in runs))
    tally.note(CATEGORY, "tick p99 [ms]", p99)
    tally.note(CATEGORY, "tick max [ms]", max(m["tick_latency_ms"]["max"] for m in runs))
    tally.note(CATEGORY, "suggestions", sum(m["suggestions"] for m in runs))
    model = [m["model_latency_ms"] for m in runs if m["model_latency_ms"]]
    if model:
        tally.note(CATEGORY, "model p50 [ms]", max(m["p50"] for m in model))
    return ticks, missed, p99


def test_fsm_keeps_its_deadline_with_a_slow_model_quick(
    tmp_path: Path, tally: Any, perception_ms: list[float]
) -> None:
    backend = SlowModel(0.2)
    metrics = realtime_episode(tmp_path, "quick", 400, backend)
    ticks, missed, p99 = record(tally, [metrics])
    context = note_environment(tally, perception_ms)
    assert ticks == 400 and backend.calls > 0 and metrics["suggestions"] > 0, metrics
    assert metrics["scheduling"] in ("fifo", "nice-5", "normal"), metrics  # what the loop thread got
    tally.note(CATEGORY, "loop scheduling", metrics["scheduling"])
    # The loop never waits for the model: a loop that waited for this 200 ms model would spend >= 200 ms
    # in a tick for every call. (The p99 speed target is the reliability suite's, below: a timed bound
    # in the default suite failed on this shared machine at load 0.5 on unchanged code.)
    assert metrics["tick_latency_ms"]["max"] < 20.0, f"{metrics['tick_latency_ms']}; {missed} missed slots; {context}"


@pytest.mark.slow
@pytest.mark.reliability
def test_fsm_tick_latency_p99_with_a_slow_model(tmp_path: Path, tally: Any, perception_ms: list[float]) -> None:
    """The controller's own tick work (tick start -> command published) at p99 <= P99_LIMIT_MS."""
    backend = SlowModel(0.2)
    metrics = realtime_episode(tmp_path, "p99", 2000, backend)
    ticks, missed, p99 = record(tally, [metrics])
    context = note_environment(tally, perception_ms)
    assert ticks == 2000 and metrics["suggestions"] > 0, metrics
    assert p99 <= P99_LIMIT_MS, f"{metrics['tick_latency_ms']}; {missed} missed slots; {context}"


@pytest.mark.slow
@pytest.mark.reliability
def test_fsm_keeps_its_deadline_beside_the_live_view(tmp_path: Path, tally: Any, perception_ms: list[float]) -> None:
    """`drive --realtime` shows the rich live table: its refresh thread must not delay the loop."""
    import io

    from rich.console import Console

    from llmnav.reporting.live import LiveView

    backend = SlowModel(0.2)
    screen = io.StringIO()
    console = Console(file=screen, force_terminal=True, width=100)
    spec = EpisodeSpec(scenario="maze_arena", task_id="M1", options=drive_options(planner="fsm"), out_dir=tmp_path)
    with LiveView(console, spec) as view:
        metrics = realtime_episode(tmp_path, "live", 2000, backend, view=view)
    ticks, missed, p99 = record(tally, [metrics])
    context = note_environment(tally, perception_ms)
    assert "APPROACH" in screen.getvalue() or "SEARCH" in screen.getvalue()  # the table was drawn
    assert ticks == 2000 and missed == 0, f"{metrics['tick_latency_ms']}; {missed} missed slots; {context}"
    assert p99 <= P99_LIMIT_MS, f"{metrics['tick_latency_ms']}; {context}"


@contextmanager
def cpu_hog(processes: int) -> Iterator[None]:
    """`processes` ordinary processes spinning on the CPU for the block (each stopped by its pid after)."""
    spinners = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(processes)]
    try:
        yield
    finally:
        for spinner in spinners:
            spinner.kill()
            spinner.wait()


@contextmanager
def model_generating_beside(out: Path) -> Iterator[Path]:
    """A second copy of the local model generating all the time in its own process; one line per answer.

    Grammar-constrained like every planner's request. It keeps a core busy with model work beside the
    loop, as another client of the machine would.
    """
    code = (
        "from llmnav.backends.local import LocalBackend\n"
        "from llmnav.backends.base import ChatRequest, Message\n"
        "from llmnav.planners.fsm.answers import VelocitySuggestion\n"
        "busy = LocalBackend()\n"
        "request = ChatRequest(messages=(Message('system', \"You advise a robot's speed.\"),"
        " Message('user', '{\"distance\": 0.8}')), json_schema=VelocitySuggestion.model_json_schema(),"
        " max_tokens=64)\n"
        "while True:\n"
        "    busy.chat(request)\n"
        "    print('answered', flush=True)\n"
    )
    here = str(Path(llmnav.__file__).parents[1])  # the llmnav under test, in the child too
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([here, os.environ.get("PYTHONPATH", "")])}
    with out.open("w") as lines:
        generator = subprocess.Popen([sys.executable, "-c", code], stdout=lines, env=env)
        try:
            yield out
        finally:
            generator.kill()
            generator.wait()


def wait_for_load(level: float, timeout_s: float) -> float:
    """The 1-minute load average once it is >= `level` (or when `timeout_s` has passed)."""
    deadline = time.monotonic() + timeout_s
    while os.getloadavg()[0] < level and time.monotonic() < deadline:
        time.sleep(2.0)
    return os.getloadavg()[0]


@pytest.mark.slow
@pytest.mark.reliability
def test_fsm_keeps_its_deadline_with_the_local_model_full(
    tmp_path: Path, tally: Any, perception_ms: list[float]
) -> None:
    from llmnav.backends.local import LocalBackend

    backend = LocalBackend()  # loaded in the model's own process by the FSM, not in this one
    runs: list[dict[str, Any]] = []
    with cpu_hog(HOG_PROCESSES), model_generating_beside(tmp_path / "generated.txt") as generated_lines:
        load_at_start = wait_for_load(HOG_LOAD, HOG_WAIT_S)
        assert load_at_start >= HOG_LOAD, f"load {load_at_start:.2f} after {HOG_WAIT_S:.0f} s with the hog"
        remaining = 10_000
        while remaining > 0:
            runs.append(realtime_episode(tmp_path, f"full-{len(runs)}", remaining, backend))
            remaining -= runs[-1]["ticks"]
        load_at_end = os.getloadavg()[0]
    generated = generated_lines.read_text().count("answered")
    ticks, missed, p99 = record(tally, runs)
    tally.note(CATEGORY, "background generations", generated)
    tally.note(CATEGORY, "load avg at start / end of the ticks", f"{load_at_start:.2f} / {load_at_end:.2f}")
    tally.note(CATEGORY, "loop scheduling", runs[0]["scheduling"])
    context = note_environment(tally, perception_ms)
    assert ticks >= 10_000 and generated > 0 and sum(m["suggestions"] for m in runs) > 0
    assert {m["model_in"] for m in runs} == {"process"}, "the loop's process must not hold the model"
    assert load_at_end >= HOG_LOAD, f"the load fell to {load_at_end:.2f} during the run"
    assert missed == 0, f"{[m['missed_deadlines'] for m in runs]} missed deadlines; {context}"
    assert p99 <= P99_LIMIT_MS, [m["tick_latency_ms"] for m in runs]
