"""Per-decision overhead of the stepwise loop outside the model: sim, sensors, prompt, guard, logging.

A canned backend answers instantly (FRONT 1 m and ROTATE_LEFT 90° in turn, a turn after a veto), so the
wall time of a decision is everything llmnav itself spends. Measured on the factory, LiDAR only and with
the 640×480 camera, as the median gap between consecutive `observation` events of the run log, split by
the log's own timestamps into sensors, decision (prompt, guard, veto, logging) and motion.
Target: ≤ 10 % of a warm local-model decision (1.6–2.3 s measured here, so ≤ 160 ms at the fast end).
Quick mode: one episode of 4 decisions per row; no target is judged.
"""

from __future__ import annotations

import os
import statistics
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

from bench import judged, quick_from_env
from llmnav.backends.base import Backend, ChatRequest, ChatResult
from llmnav.planners.base import drive_options
from llmnav.runs.runlog import read_run
from llmnav.runs.runner import EpisodeSpec, run_episode

WARM_DECISION_S = (1.6, 2.3)  # [s] warm local-model decision (docs/sources.md, M)
TARGET_SHARE = 0.10
ITERATIONS = 12
REPEATS = 3
QUICK_ITERATIONS = 4  # [decisions]: three gaps between observations, enough for the p90

_FRAME = '{"goal": "g", "reasoning": "r", "scene_description": "s", "action": %s}'
_MOVE = _FRAME % '{"command": "FRONT", "parameters": 1.0}'
_TURN = _FRAME % '{"command": "ROTATE_LEFT", "parameters": 90}'


class InstantBackend(Backend):
    """Answers at once: move and turn in turn; a turn whenever the last message is a veto."""

    name = "instant"

    def __init__(self) -> None:
        super().__init__(None)
        self.calls = 0

    def chat(self, request: ChatRequest) -> ChatResult:
        """A canned answer with zero latency."""
        self.calls += 1
        last = request.messages[-1].text
        text = _TURN if "Safety check" in last or self.calls % 2 == 0 else _MOVE
        return ChatResult(text=text, latency_s=0.0, model="instant")


@dataclass
class Phases:
    """Per-decision wall times [s] of one or more episodes, split by what the log's timestamps bracket."""

    total: list[float] = field(default_factory=list)  # observation to next observation
    sensors: list[float] = field(default_factory=list)  # previous action logged -> observation logged
    decide: list[float] = field(default_factory=list)  # observation -> last guard verdict (prompt, model, guard)
    motion: list[float] = field(default_factory=list)  # last guard verdict -> action logged (the sim drives)


def _episode_phases(sensing: tuple[str, ...], phases: Phases, iterations: int = ITERATIONS) -> None:
    """Run one episode with the instant backend and add its per-decision phases."""
    with tempfile.TemporaryDirectory() as tmp:
        # max_vetoes is the stepwise planner's own option: its options model, not the shared DriveOptions
        options = drive_options("stepwise", sensing=sensing, max_iterations=iterations, max_vetoes=5)
        spec = EpisodeSpec(
            scenario="factory",
            task_id="T7",
            task_text=None,
            start_pose=1,
            options=options,
            backend="instant",
            out_dir=Path(tmp) / "run",
        )
        run_episode(spec, backend_obj=InstantBackend())
        events = read_run(Path(tmp) / "run").events
    by_step: dict[int, dict[str, float]] = {}
    for event in events:
        step = event.get("step")
        if isinstance(step, int) and event["type"] in ("observation", "guard", "action"):
            by_step.setdefault(step, {})[event["type"]] = event["t_wall"]  # the last of each type wins
    steps = sorted(s for s, marks in by_step.items() if len(marks) == 3)
    for step in steps:
        marks, before = by_step[step], by_step.get(step - 1, {})
        if "action" in before:
            phases.sensors.append(marks["observation"] - before["action"])
            phases.total.append(marks["observation"] - before["observation"])
        phases.decide.append(marks["guard"] - marks["observation"])
        phases.motion.append(marks["action"] - marks["guard"])


def _ms(values: list[float]) -> float:
    return statistics.median(values) * 1000.0


def main(quick: bool = False) -> None:
    """Print the per-decision overhead table (quick: one short episode a row, not a measurement)."""
    iterations, repeats = (QUICK_ITERATIONS, 1) if quick else (ITERATIONS, REPEATS)
    budget_ms = TARGET_SHARE * WARM_DECISION_S[0] * 1000.0
    mode = ", quick: not a measurement" if quick else ""
    print(f"bench.decision: stepwise loop outside the model, factory, {iterations} decisions x {repeats} runs{mode}")
    print("median wall time per decision [ms]: sensors (scan, camera, JPEG, observation log), decide (prompt,")
    print("instant model, guard, veto, call log), motion (physics of the executed action)")
    columns = [("decision", 9), ("p90", 7), ("sensors", 9), ("decide", 8), ("motion", 8)]
    columns += [("target", 8), ("ratio", 7), ("", 6)]
    print(f"{'sensing':<24}" + "".join(f"{name:>{width}}" for name, width in columns))
    for label, sensing in (("lidar", ("lidar",)), ("lidar + camera 640x480", ("lidar", "image"))):
        phases = Phases()
        for _ in range(repeats):
            _episode_phases(sensing, phases, iterations)
        total = _ms(phases.total)
        p90 = statistics.quantiles(phases.total, n=10)[-1] * 1000.0
        print(
            f"{label:<24}{total:>9.1f}{p90:>7.0f}{_ms(phases.sensors):>9.1f}{_ms(phases.decide):>8.1f}"
            f"{_ms(phases.motion):>8.1f}{budget_ms:>8.0f}{total / budget_ms:>7.2f}"
            f"  {judged('ok' if total <= budget_ms else 'FAIL', quick)}"
        )
    low, high = WARM_DECISION_S
    print(
        f"target: <= {TARGET_SHARE:.0%} of a warm local decision ({low}-{high} s); "
        f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores"
    )


if __name__ == "__main__":
    main(quick=quick_from_env())
