"""Per-decision overhead of the stepwise loop outside the model: sim, sensors, prompt, guard, logging.

A canned backend answers instantly (FRONT 1 m and ROTATE_LEFT 90° in turn, a turn after a veto), so the
wall time of a decision is everything llmnav itself spends. Measured on the factory, LiDAR only and with
the 640×480 camera, as the median gap between consecutive `observation` events of the run log.
Target: ≤ 10 % of a warm local-model decision (1.6–2.3 s measured here, so ≤ 160 ms at the fast end).
"""

from __future__ import annotations

import os
import statistics
import tempfile
import time
from pathlib import Path

from llmnav.backends.base import Backend, ChatRequest, ChatResult
from llmnav.planners.base import DriveOptions
from llmnav.runlog import read_run
from llmnav.runner import EpisodeSpec, run_episode

WARM_DECISION_S = (1.6, 2.3)  # [s] warm local-model decision (SPEC E)
TARGET_SHARE = 0.10
ITERATIONS = 12
REPEATS = 3

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


def _decision_gaps(sensing: tuple[str, ...]) -> tuple[list[float], float]:
    """Gaps [s] between consecutive observations of one episode, and the episode's wall time [s]."""
    with tempfile.TemporaryDirectory() as tmp:
        options = DriveOptions(planner="stepwise", sensing=sensing, max_iterations=ITERATIONS, max_vetoes=5)  # type: ignore[arg-type]
        spec = EpisodeSpec(
            scenario="factory",
            task_id="T7",
            task_text=None,
            start_pose=1,
            options=options,
            backend="instant",
            out_dir=Path(tmp) / "run",
        )
        t0 = time.perf_counter()
        run_episode(spec, backend_obj=InstantBackend())
        wall = time.perf_counter() - t0
        times = [e["t_wall"] for e in read_run(Path(tmp) / "run").of_type("observation")]
    return [b - a for a, b in zip(times, times[1:], strict=False)], wall


def _camera_ms(repeats: int = 5) -> float:
    """Median cost [ms] of one 640x480 frame + JPEG on the factory: the share of the camera decision that is
    the renderer itself (TinyRenderer; SPEC F measured about 100 ms on an idle machine)."""
    from llmnav.scenario import load_scenario
    from llmnav.sim.world import World

    scenario = load_scenario("factory")
    with World(scenario) as world:
        world.reset(scenario.task("T7").start_poses[0].pose())
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            world.camera.capture().image()
            times.append(time.perf_counter() - t0)
    return statistics.median(times) * 1000.0


def main() -> None:
    """Print the per-decision overhead table."""
    budget_ms = TARGET_SHARE * WARM_DECISION_S[0] * 1000.0
    print(
        f"bench.decision: stepwise loop outside the model, factory, {ITERATIONS} decisions x {REPEATS} runs"
    )
    print(f"{'sensing':<22}{'median/decision':>17}{'p90':>9}{'episode':>10}{'target':>10}{'ratio':>8}")
    for label, sensing in (("lidar", ("lidar",)), ("lidar + camera 640x480", ("lidar", "image"))):
        gaps: list[float] = []
        walls: list[float] = []
        for _ in range(REPEATS):
            run_gaps, wall = _decision_gaps(sensing)
            gaps += run_gaps
            walls.append(wall)
        median_ms = statistics.median(gaps) * 1000.0
        p90_ms = statistics.quantiles(gaps, n=10)[-1] * 1000.0
        print(
            f"{label:<22}{median_ms:>14.1f} ms{p90_ms:>6.0f} ms{statistics.median(walls):>8.2f} s"
            f"{budget_ms:>7.0f} ms{median_ms / budget_ms:>8.2f}"
        )
    load = os.getloadavg()[0]
    print(f"of which one 640x480 camera frame + JPEG: {_camera_ms():.1f} ms (median); load avg {load:.1f}")
    low, high = WARM_DECISION_S
    print(f"target: <= {TARGET_SHARE:.0%} of a warm local decision ({low}-{high} s)")


if __name__ == "__main__":
    main()
