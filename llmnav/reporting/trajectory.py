"""The trajectory figure of one run: the top view, the driven path, numbered steps and the oracle path.

Start in green, end in red, each executed action's end pose numbered by its step, the oracle's shortest
path dashed (skipped when the oracle cannot plan one). Drawn from the run log alone plus the scenario.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

from llmnav.errors import LlmnavError

if TYPE_CHECKING:
    from llmnav.runlog import RunRecord
    from llmnav.scenario import Scenario, Task

FIG_WIDTH_IN = 8.0  # [in]
DPI = 120
SAME_SPOT_M = 0.15  # [m] step ends closer than this share one label
HEADING_ARROW_M = 0.8  # [m] length of the start and end heading arrows


def _oracle_points(scenario: Scenario, task: Task, start: list[float]) -> list[tuple[float, float]] | None:
    """The oracle's path from the start pose, or None when there is no baseline or no target path."""
    if task.kind != "target":
        return None
    try:
        from llmnav.geometry import Pose2D
        from llmnav.mapping.targets import oracle_path

        path = oracle_path(scenario, task, Pose2D.from_list(start))
    except (ImportError, LlmnavError):
        return None
    if path is None:
        return None
    # The shortcut path (what a robot following the oracle drives), not the raw grid staircase.
    return [(start[0], start[1]), *((float(x), float(y)) for x, y in path.waypoints)]


def plot_record(record: RunRecord, scenario: Scenario, task: Task, out_path: Path) -> Path:
    """Draw a run record onto the scenario's top view and save it as PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from llmnav.reporting.topview import draw_scenario

    poses = record.poses()
    (x0, x1), (y0, y1) = scenario.bounds.x, scenario.bounds.y
    fig, ax = plt.subplots(figsize=(FIG_WIDTH_IN, FIG_WIDTH_IN * (y1 - y0) / max(x1 - x0, 1e-6) + 0.6))
    try:
        draw_scenario(ax, scenario)
        start = record.config.get("start_pose") or (poses[0] if poses else None)
        if start is not None:
            oracle = _oracle_points(scenario, task, start)
            if oracle:
                ax.plot(
                    *zip(*oracle, strict=True), "--", color="0.35", lw=1.4, label="oracle path", zorder=5.5
                )
        if poses:
            xs, ys = [p[0] for p in poses], [p[1] for p in poses]
            ax.plot(xs, ys, "-", color="tab:blue", lw=2.0, label="robot path", zorder=5)
            ax.plot(xs[0], ys[0], "o", color="green", ms=9, label="start", zorder=6)
            ax.plot(xs[-1], ys[-1], "o", color="red", ms=9, label="end", zorder=6)
            _heading(ax, poses[0], "green")
            _heading(ax, poses[-1], "red")
        _number_steps(ax, record.of_type("action"))
        outcome = (record.of_type("end") or [{}])[-1].get("outcome", "cut short")
        ax.set_title(
            f"{scenario.name} · {task.id}: {task.text} · {record.config.get('planner')} · {outcome}",
            fontsize=9,
        )
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7, frameon=False)
        out_path = Path(out_path)
        fig.savefig(out_path, dpi=DPI, bbox_inches="tight")
    finally:
        plt.close(fig)
    return out_path


def _number_steps(ax: Any, actions: list[dict[str, Any]]) -> None:
    """Label each step's end pose with its number; steps ending at one spot (turns) share a label."""
    ends: dict[Any, list[float]] = {}
    for action in actions:
        if action.get("pose_after") is not None:
            ends[action.get("step")] = action["pose_after"]
    spots: dict[tuple[int, int], list[str]] = {}
    where: dict[tuple[int, int], list[float]] = {}
    for step, pose in ends.items():
        key = (round(pose[0] / SAME_SPOT_M), round(pose[1] / SAME_SPOT_M))
        spots.setdefault(key, []).append(str(step))
        where.setdefault(key, pose)
    for key, steps in spots.items():
        pose = where[key]
        label = ",".join(steps) if len(steps) <= 4 else f"{steps[0]}–{steps[-1]}"
        ax.annotate(
            label,
            (pose[0], pose[1]),
            xytext=(4, 4),
            textcoords="offset points",
            fontsize=7,
            color="tab:blue",
            zorder=7,
        )


def _heading(ax: Any, pose: list[float], color: str) -> None:
    """An arrow along a pose's heading."""
    dx, dy = HEADING_ARROW_M * math.cos(pose[2]), HEADING_ARROW_M * math.sin(pose[2])
    ax.annotate(
        "",
        (pose[0] + dx, pose[1] + dy),
        (pose[0], pose[1]),
        arrowprops={"arrowstyle": "->", "color": color, "lw": 1.5},
        zorder=6,
    )
