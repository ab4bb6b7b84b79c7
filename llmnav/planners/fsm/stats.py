"""The FSM's counters during an episode, and its metrics.

Those known when `run` ends come from the counters; those of the closed run log (the path it drove, its
pose samples) from the `summarize` hook.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from llmnav.core.geometry import path_length
from llmnav.mapping.paths import shortest_path_length
from llmnav.planners.fsm.oracle import sign_stop_point

if TYPE_CHECKING:
    from llmnav.core.geometry import Pose2D
    from llmnav.runs.runlog import RunRecord
    from llmnav.world.scenario import Scenario, Task


@dataclass
class FsmStats:
    """Counters behind the FSM table of `llmnav score`."""

    tick_latency_ms: list[float] = field(default_factory=list)
    model_latency_ms: list[float] = field(default_factory=list)
    suggestions: int = 0
    rejected: dict[str, int] = field(default_factory=lambda: {"stale": 0, "bounds": 0, "parse": 0, "error": 0})
    accepted: int = 0
    ticks_using: int = 0
    missed_deadlines: int = 0
    scheduling: str = "simulated"  # the loop thread's policy under --realtime (llmnav.core.realtime)
    model_in: str = "loop"  # where the model runs: called between ticks, a worker "thread" or a "process"
    assist_failed: str | None = None  # what ended the model's worker mid-episode (the run went on without it)


def run_metrics(stats: FsmStats, assist: str, final: Pose2D, stop: tuple[float, float] | None) -> dict[str, Any]:
    """The episode's metrics known when `run` ends: e_pos to the stop point, ticks and suggestions."""
    e_pos = final.distance_to(*stop) if stop is not None else None
    ticks = max(len(stats.tick_latency_ms), 1)
    lat = np.asarray(stats.tick_latency_ms or [0.0])
    model = np.asarray(stats.model_latency_ms) if stats.model_latency_ms else None
    return {
        "assist": assist,
        "e_pos_m": e_pos,
        "ticks": len(stats.tick_latency_ms),
        "missed_deadlines": stats.missed_deadlines,
        "scheduling": stats.scheduling,
        "model_in": stats.model_in,
        "tick_latency_ms": {
            "mean": float(lat.mean()),
            "p50": float(np.percentile(lat, 50)),
            "p99": float(np.percentile(lat, 99)),
            "max": float(lat.max()),
        },
        "model_latency_ms": None
        if model is None
        else {
            "mean": float(model.mean()),
            "p50": float(np.percentile(model, 50)),
            "max": float(model.max()),
        },
        "suggestions": stats.suggestions,
        "accepted": stats.accepted,
        "rejected": dict(stats.rejected),
        "r_acc": stats.accepted / stats.suggestions if stats.suggestions else None,
        "r_use": stats.ticks_using / ticks,
    }


def log_metrics(record: RunRecord, scenario: Scenario) -> dict[str, Any]:
    """The metrics of the closed log: the driven length L_real and eta = L_opt / L_real.

    L_opt joins the same two points as the driven path, its first and its last pose sample: so eta <= 1 by
    definition, also for an episode that stopped short of the sign (L_opt to the sign, as before, gave a
    robot that stopped early an eta above 1). L_opt is the A* length on the true map, capped by L_real,
    because the driven path is itself a collision-free path between the two points (the grid's corners
    can make A* a little longer than a path that hugs a wall). Nothing for an episode whose `end` event
    carries no FSM metrics (one aborted before its first tick); eta is None when A* finds no path.
    """
    ends = record.of_type("end")
    metrics = ends[-1].get("metrics") if ends else None
    if not isinstance(metrics, dict) or "e_pos_m" not in metrics:
        return {}
    poses = record.poses()
    real = path_length(poses)  # [m]
    if len(poses) < 2 or real <= 0:
        return {"eta": None, "real_length_m": real, "optimal_length_m": None}
    shortest = _shortest_length(scenario, (poses[0][0], poses[0][1]), (poses[-1][0], poses[-1][1]))
    optimal = None if shortest is None else min(shortest, real)  # [m]
    return {"eta": None if optimal is None else optimal / real, "real_length_m": real, "optimal_length_m": optimal}


def _shortest_length(scenario: Scenario, start: tuple[float, float], stop: tuple[float, float]) -> float | None:
    """L_opt [m]: the A* length on the scenario's true map between the driven path's two ends."""
    return shortest_path_length(scenario, start, stop)


def stop_point(scenario: Scenario, task: Task, d_goal: float) -> tuple[float, float] | None:
    """p_target of e_pos: where the FSM should stop, `d_goal` in front of the target sign (None: no target).

    A target with an explicit goal point (or a point target) is used as it is.
    """
    if not task.targets:
        return None
    target = task.targets[0]
    if target.object is None:
        return scenario.target_points(task)[0]
    return sign_stop_point(scenario, scenario.object(target.object), d_goal)
