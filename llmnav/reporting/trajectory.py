"""The trajectory figure of one run: the top view, the driven path, numbered steps and the oracle path.

Start in green, end in red, the target as a star inside its success-radius circle, each executed action's
end pose numbered by its step (labels placed clear of each other, the object names and the start and end
markers), the oracle's shortest path dashed (skipped when the oracle cannot plan one). Drawn from the run
log alone plus the scenario.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

from llmnav.core.geometry import Pose2D
from llmnav.errors import LlmnavError, printable
from llmnav.scoring.metrics import SUCCESS_RADIUS_M

if TYPE_CHECKING:
    from llmnav.runs.runlog import RunRecord
    from llmnav.world.scenario import Scenario, Task

FIG_WIDTH_IN = 8.0  # [in]
DPI = 120
SAME_SPOT_M = 0.15  # [m] step ends closer than this share one label
HEADING_ARROW_M = 0.8  # [m] length of the start and end heading arrows
MARKER_PT = 9  # [pt] start and end marker size


def oracle_points(scenario: Scenario, task: Task, start: list[float]) -> list[tuple[float, float]] | None:
    """The oracle's path from the start pose, or None when there is no baseline or no target path."""
    if task.kind != "target":
        return None
    try:
        # deferred: the oracle path brings numpy (about 0.1 s), only for target tasks
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
    # deferred: matplotlib (about 0.3 s) loads only when a figure is drawn
    import matplotlib

    matplotlib.use("Agg")
    # deferred with matplotlib: pyplot comes after the Agg backend is chosen
    import matplotlib.pyplot as plt

    (x0, x1), (y0, y1) = scenario.bounds.x, scenario.bounds.y
    fig, ax = plt.subplots(figsize=(FIG_WIDTH_IN, FIG_WIDTH_IN * (y1 - y0) / max(x1 - x0, 1e-6) + 0.6), dpi=DPI)
    try:
        draw_record(ax, record, scenario, task)
        out_path = Path(out_path)
        fig.savefig(out_path, dpi=DPI, bbox_inches="tight")
    finally:
        plt.close(fig)
    return out_path


def draw_record(ax: Any, record: RunRecord, scenario: Scenario, task: Task) -> None:
    """The run on `ax`: top view, target and success radius, oracle path, driven path, numbered steps."""
    # deferred: the top view brings pydantic and yaml (about 0.15 s), only when a run is drawn
    from llmnav.reporting.topview import draw_scenario, draw_targets, label_fontsize, place_labels

    poses = record.poses()
    draw_scenario(ax, scenario, labels=False)  # object names last, placed clear of the run's markers
    if task.kind == "target" and task.targets:
        radius = (record.summary or {}).get("success_radius_m")
        radius_m = float(radius) if isinstance(radius, (int, float)) and radius > 0 else SUCCESS_RADIUS_M
        draw_targets(ax, scenario.target_points(task), radius_m)
    start = record.config.get("start_pose") or (poses[0] if poses else None)
    if start is not None:
        oracle = oracle_points(scenario, task, start)
        if oracle:
            ax.plot(*zip(*oracle, strict=True), "--", color="0.35", lw=1.4, label="oracle path", zorder=5.5)
    markers = []
    if poses:
        xs, ys = [p[0] for p in poses], [p[1] for p in poses]
        ax.plot(xs, ys, "-", color="tab:blue", lw=2.0, label="robot path", zorder=5)
        markers += ax.plot(xs[0], ys[0], "o", color="green", ms=MARKER_PT, label="start", zorder=6)
        markers += ax.plot(xs[-1], ys[-1], "o", color="red", ms=MARKER_PT, label="end", zorder=6)
        _heading(ax, poses[0], "green")
        _heading(ax, poses[-1], "red")
    outcome = (record.of_type("end") or [{}])[-1].get("outcome", "cut short")
    ax.set_title(
        printable(f"{scenario.name} · {task.id}: {task.text} · {record.config.get('planner')} · {outcome}"),
        fontsize=9,
    )
    renderer = ax.figure.canvas.get_renderer()
    ax.apply_aspect()
    stars = [line for line in ax.lines if line.get_marker() == "*"]
    avoid = [m.get_window_extent(renderer) for m in (*markers, *stars)]
    place_labels(ax, scenario, fontsize=label_fontsize(scenario), avoid=avoid)
    _number_steps(ax, record.of_type("action"), avoid)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7, frameon=False)


def _number_steps(ax: Any, actions: list[dict[str, Any]], avoid: list[Any]) -> None:
    """Label each step's end pose with its number, clear of the other labels and the start and end markers.

    Steps ending at one spot (turns) share a label.
    """
    # deferred: the top view brings pydantic and yaml (about 0.15 s), only when a run is drawn
    from llmnav.reporting.topview import place_point_labels

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
    items = [
        (",".join(steps) if len(steps) <= 4 else f"{steps[0]}–{steps[-1]}", where[key]) for key, steps in spots.items()
    ]
    place_point_labels(ax, items, fontsize=7, color="tab:blue", avoid=avoid)


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
