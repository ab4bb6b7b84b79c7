"""Top-down drawings of a scenario: walls, obstacles, labelled objects, corridors and start poses.

`draw_scenario` paints onto a matplotlib Axes so other plots (trajectories) can draw on top of it;
`plot_scenario` writes a stand-alone PNG. matplotlib is imported lazily with the Agg backend so that
importing this module costs nothing for commands that never plot.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

from llmnav.errors import printable
from llmnav.scenario import LabelledObject, Scenario, Shape, Task

if TYPE_CHECKING:
    from matplotlib.axes import Axes

_WALL_RGBA = (0.25, 0.25, 0.25, 1.0)
_CORRIDOR_RGBA = (0.55, 0.75, 0.95, 0.18)
_NON_SOLID_ALPHA = 0.55  # non-solid objects (plates, signs, markers) drawn lighter and dashed


def _pyplot() -> Any:
    """matplotlib.pyplot with the non-interactive Agg backend (no display needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _patch(shape: Shape, *, color: tuple[float, ...], edge: tuple[float, ...], dashed: bool = False) -> Any:
    """A matplotlib patch for a footprint (rotated rectangle or circle)."""
    from matplotlib.patches import Circle, Rectangle

    style: dict[str, Any] = {
        "facecolor": color,
        "edgecolor": edge,
        "linewidth": 0.6,
        "linestyle": "--" if dashed else "-",
    }
    if shape.shape == "cylinder":
        assert shape.radius is not None
        return Circle(shape.center, shape.radius, **style)
    assert shape.size is not None
    sx, sy = shape.size
    corner = (shape.center[0] - sx / 2, shape.center[1] - sy / 2)
    return Rectangle(corner, sx, sy, angle=shape.yaw_deg, rotation_point="center", **style)


def draw_scenario(ax: Axes, scenario: Scenario, *, labels: bool = True) -> None:
    """Draw the scenario's static world onto `ax` (equal aspect, metres)."""
    from matplotlib.patches import Rectangle

    bx, by = scenario.bounds.x, scenario.bounds.y
    ax.add_patch(
        Rectangle(
            (bx[0], by[0]),
            bx[1] - bx[0],
            by[1] - by[0],
            facecolor=scenario.floor_color[:3],
            alpha=0.25,
            edgecolor="none",
            zorder=0,
        )
    )
    for corridor in scenario.corridors:
        ax.add_patch(
            Rectangle(
                (corridor.x[0], corridor.y[0]),
                corridor.x[1] - corridor.x[0],
                corridor.y[1] - corridor.y[0],
                facecolor=_CORRIDOR_RGBA,
                edgecolor=(0.3, 0.5, 0.8, 0.5),
                linewidth=0.6,
                linestyle=":",
                zorder=1,
            )
        )
    for wall in scenario.walls:
        ax.add_patch(_patch(wall, color=_WALL_RGBA, edge=_WALL_RGBA)).set_zorder(3)
    for obstacle in scenario.obstacles:
        ax.add_patch(_patch(obstacle, color=obstacle.color, edge=(0.1, 0.1, 0.1, 1.0))).set_zorder(3)
    # Small labels for dense worlds (corridor_c has ~40 objects); big worlds get a smaller font.
    extent = max(bx[1] - bx[0], by[1] - by[0])
    fontsize = 6.5 if extent > 12 else 7.5
    placed: list[tuple[float, float, str]] = []  # labels so far (anchor, text), to keep neighbours apart
    for obj in scenario.objects:
        face = obj.color if obj.solid else (*obj.color[:3], _NON_SOLID_ALPHA)
        patch = ax.add_patch(_patch(obj, color=face, edge=(0.1, 0.1, 0.1, 1.0), dashed=not obj.solid))
        patch.set_zorder(4)
        if obj.goal is not None:
            ax.plot(*obj.goal, marker="x", markersize=3, color=(0.3, 0.3, 0.3), zorder=5)
        if labels:
            _label(ax, obj, placed, extent=extent, fontsize=fontsize)
    ax.set_xlim(bx[0] - 0.3, bx[1] + 0.3)
    ax.set_ylim(by[0] - 0.3, by[1] + 0.3)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.grid(True, linewidth=0.3, alpha=0.4)


def _label(
    ax: Axes, obj: LabelledObject, placed: list[tuple[float, float, str]], *, extent: float, fontsize: float
) -> None:
    """Label an object above its footprint, or below when a neighbour's label is close by.

    When both spots are taken by a label with the same text (a cluster of barrels), one label is enough.
    """
    half_y = obj.half_extents()[1]
    spots = [
        ((obj.center[0], obj.center[1] + half_y), False),
        ((obj.center[0], obj.center[1] - half_y), True),
    ]

    def near(x: float, y: float) -> list[str]:
        return [t for px, py, t in placed if abs(px - x) < 0.12 * extent and abs(py - y) < 0.03 * extent]

    free = [(anchor, below) for anchor, below in spots if not near(*anchor)]
    if not free and any(obj.label in near(*anchor) for anchor, _ in spots):
        return
    anchor, below = free[0] if free else spots[0]
    placed.append((anchor[0], anchor[1], obj.label))
    ax.annotate(
        obj.label,
        anchor,
        textcoords="offset points",
        xytext=(0, -1.5 if below else 1.5),
        ha="center",
        va="top" if below else "bottom",
        fontsize=fontsize,
        color=(0.1, 0.1, 0.1),
        zorder=6,
    )


def _draw_start_poses(ax: Axes, scenario: Scenario, task: Task | None) -> None:
    """Numbered arrows for the start poses (all tasks' when `task` is None)."""
    tasks = [task] if task is not None else scenario.tasks
    length = 0.06 * max(
        scenario.bounds.x[1] - scenario.bounds.x[0], scenario.bounds.y[1] - scenario.bounds.y[0]
    )
    length = min(max(length, 0.3), 1.0)  # [m] arrow length, readable at any map size
    seen: dict[tuple[float, float, float], int] = {}
    cmap = _pyplot().get_cmap("tab10")
    for ti, t in enumerate(tasks):
        colour = cmap(ti % 10)
        for si, start in enumerate(scenario.start_poses(t)):
            key = (start.x, start.y, start.yaw_deg)
            stacked = seen.get(key, 0)  # identical poses of several tasks: offset their numbers
            seen[key] = stacked + 1
            yaw = math.radians(start.yaw_deg)
            ax.arrow(
                start.x,
                start.y,
                length * math.cos(yaw),
                length * math.sin(yaw),
                width=length * 0.08,
                head_width=length * 0.35,
                head_length=length * 0.35,
                length_includes_head=True,
                color=colour,
                zorder=7,
            )
            tag = f"{si + 1}" if task is not None else f"{t.id}.{si + 1}"
            ax.annotate(
                tag,
                (start.x, start.y),
                textcoords="offset points",
                xytext=(-4, -9 - 8 * stacked),
                fontsize=6.5,
                color=colour,
                ha="right",
                zorder=8,
            )


def plot_scenario(scenario: Scenario, path: str | Path, *, task: Task | None = None) -> Path:
    """Write a top view PNG of the scenario with numbered start-pose arrows; returns the path written."""
    plt = _pyplot()
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    bx, by = scenario.bounds.x, scenario.bounds.y
    aspect = (by[1] - by[0]) / (bx[1] - bx[0])
    width = 10.0  # [in]
    fig, ax = plt.subplots(figsize=(width, min(max(width * aspect, 3.0), 16.0)))
    try:
        draw_scenario(ax, scenario)
        _draw_start_poses(ax, scenario, task)
        title = scenario.name if task is None else f"{scenario.name} - {task.id}: {task.text}"
        ax.set_title(printable(title), fontsize=10)
        fig.tight_layout()
        fig.savefig(out, dpi=130)
    finally:
        plt.close(fig)
    return out
