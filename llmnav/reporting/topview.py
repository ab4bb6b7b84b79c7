"""Top-down drawings of a scenario: walls, obstacles, labelled objects, corridors and start poses.

`draw_scenario` paints onto a matplotlib Axes so other plots (trajectories) can draw on top of it;
`plot_scenario` writes a stand-alone PNG. matplotlib is imported lazily with the Agg backend so that
importing this module costs nothing for commands that never plot.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from llmnav.errors import printable
from llmnav.scoring.metrics import SUCCESS_RADIUS_M
from llmnav.world.scenario import Scenario, Shape, Task

if TYPE_CHECKING:
    from matplotlib.axes import Axes

_WALL_RGBA = (0.25, 0.25, 0.25, 1.0)
_CORRIDOR_RGBA = (0.55, 0.75, 0.95, 0.18)
_NON_SOLID_ALPHA = 0.55  # non-solid objects (plates, signs, markers) drawn lighter and dashed


def _pyplot() -> Any:
    """matplotlib.pyplot with the non-interactive Agg backend (no display needed)."""
    # deferred: matplotlib (about 0.3 s) loads only when a figure is drawn
    import matplotlib

    matplotlib.use("Agg")
    # deferred with matplotlib: pyplot comes after the Agg backend is chosen
    import matplotlib.pyplot as plt

    return plt


def _patch(shape: Shape, *, color: tuple[float, ...], edge: tuple[float, ...], dashed: bool = False) -> Any:
    """A matplotlib patch for a footprint (rotated rectangle or circle)."""
    # deferred: matplotlib (about 0.3 s) loads only when a figure is drawn
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
    # deferred: matplotlib (about 0.3 s) loads only when a figure is drawn
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
        if wall.z > 0:  # a lintel over a doorway: drawn light and dashed, so the doorway below shows
            ax.add_patch(_patch(wall, color=(*_WALL_RGBA[:3], 0.15), edge=_WALL_RGBA, dashed=True)).set_zorder(3)
            continue
        ax.add_patch(_patch(wall, color=_WALL_RGBA, edge=_WALL_RGBA)).set_zorder(3)
    for obstacle in scenario.obstacles:
        ax.add_patch(_patch(obstacle, color=obstacle.color, edge=(0.1, 0.1, 0.1, 1.0))).set_zorder(3)
    for obj in scenario.objects:
        face = obj.color if obj.solid else (*obj.color[:3], _NON_SOLID_ALPHA)
        patch = ax.add_patch(_patch(obj, color=face, edge=(0.1, 0.1, 0.1, 1.0), dashed=not obj.solid))
        patch.set_zorder(4)
        if obj.goal is not None:
            ax.plot(*obj.goal, marker="x", markersize=3, color=(0.3, 0.3, 0.3), zorder=5)
    ax.set_xlim(bx[0] - 0.3, bx[1] + 0.3)
    ax.set_ylim(by[0] - 0.3, by[1] + 0.3)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.grid(True, linewidth=0.3, alpha=0.4)
    if labels:
        place_labels(ax, scenario, fontsize=label_fontsize(scenario))


def label_fontsize(scenario: Scenario) -> float:
    """[pt] Dense worlds (corridor_c has ~40 objects) and big ones get the smaller size."""
    bx, by = scenario.bounds.x, scenario.bounds.y
    return 7.5 if max(bx[1] - bx[0], by[1] - by[0]) > 12 else 8.5


_HALO_PT = 2.6  # [pt] the white outline behind each label: readable on dark walls and markers
_GAP_PX = 2.0  # [px] between a footprint and its label
_LEADER = {"arrowstyle": "-", "linewidth": 0.6, "color": (0.25, 0.25, 0.25), "shrinkA": 1.0, "shrinkB": 2.0}
# Where a label may go around its object, in order of preference: (dx, dy) of the label's side.
_DIRECTIONS = ((0, 1), (0, -1), (1, 0), (-1, 0), (1, 1), (-1, 1), (1, -1), (-1, -1))


def place_labels(ax: Axes, scenario: Scenario, *, fontsize: float, avoid: Sequence[Any] = ()) -> list[Any]:
    """Label every object where its text overlaps no other label, with a leader line when set apart.

    Candidate places go around the footprint, then on two wider rings (those get a leader line). Each is
    scored in display pixels: overlapping a placed label is worst, leaving the axes next, covering a
    wall, obstacle or object (a label on a dark wall) after that, distance last. A white halo keeps the
    text readable wherever it lands. A cluster of objects with the same text (barrels) gets one label.
    `avoid`: display-space boxes (a run's start and end markers, its target) that count as placed labels.
    Call it after the axes' limits and size are final; returns the annotations.
    """
    # deferred: matplotlib (about 0.3 s) loads only when a figure is drawn
    from matplotlib import patheffects
    from matplotlib.transforms import Bbox

    ax.apply_aspect()
    renderer = ax.figure.canvas.get_renderer()  # type: ignore[attr-defined]
    to_px = ax.transData.transform
    frame = ax.get_window_extent(renderer)
    px_per_pt = ax.figure.dpi / 72.0

    def footprint(shape: Shape) -> Bbox:
        hx, hy = shape.half_extents()
        x, y = shape.center
        (x0, y0), (x1, y1) = to_px([(x - hx, y - hy), (x + hx, y + hy)])
        return Bbox.from_extents(min(x0, x1), min(y0, y1), max(x0, x1), max(y0, y1))

    covers = [footprint(shape) for shape in (*scenario.walls, *scenario.obstacles, *scenario.objects)]
    probe = ax.text(0.0, 0.0, "", fontsize=fontsize)
    placed: list[tuple[Bbox, str]] = [(box, "") for box in avoid]
    annotations: list[Any] = []
    for obj in scenario.objects:
        own = footprint(obj)
        probe.set_text(obj.label)
        size = probe.get_window_extent(renderer)
        w, h = size.width + 2 * _HALO_PT * px_per_pt, size.height + _HALO_PT * px_per_pt
        if any(text == obj.label and _gap(box, own) < 1.5 * h for box, text in placed):
            continue  # its neighbour of the same name already says it
        best: tuple[float, Bbox, bool] | None = None
        for ring in (0, 1, 2):
            reach = _GAP_PX + ring * 1.6 * h
            for dx, dy in _DIRECTIONS:
                box = _beside(own, dx, dy, reach, w, h)
                score = 1000.0 * sum(box.overlaps(b) for b, _ in placed)
                score += 0.0 if frame.contains(box.x0, box.y0) and frame.contains(box.x1, box.y1) else 500.0
                score += 10.0 * sum(box.overlaps(c) for c in covers if c is not own) + 3.0 * ring
                if best is None or score < best[0]:
                    best = (score, box, ring > 0)
            if best is not None and best[0] < 10.0:
                break  # nothing in the way at this distance: no need to look farther out
        assert best is not None
        _, box, leader = best
        cx, cy = to_px(obj.center)
        annotations.append(
            ax.annotate(
                obj.label,
                obj.center,
                xytext=((box.x0 + box.width / 2 - cx) / px_per_pt, (box.y0 + box.height / 2 - cy) / px_per_pt),
                textcoords="offset points",
                ha="center",
                va="center",
                fontsize=fontsize,
                color=(0.08, 0.08, 0.08),
                zorder=6,
                path_effects=[patheffects.withStroke(linewidth=_HALO_PT, foreground="white")],
                arrowprops=_LEADER if leader else None,
            )
        )
        placed.append((box, obj.label))
    probe.remove()
    return annotations


def _beside(own: Any, dx: int, dy: int, reach: float, w: float, h: float) -> Any:
    """The w × h box on side (dx, dy) of the footprint `own`, `reach` pixels away (display coordinates)."""
    # deferred: matplotlib (about 0.3 s) loads only when a figure is drawn
    from matplotlib.transforms import Bbox

    cx = (own.x0 + own.x1) / 2 if dx == 0 else (own.x1 + reach + w / 2 if dx > 0 else own.x0 - reach - w / 2)
    cy = (own.y0 + own.y1) / 2 if dy == 0 else (own.y1 + reach + h / 2 if dy > 0 else own.y0 - reach - h / 2)
    return Bbox.from_extents(cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2)


def _gap(a: Any, b: Any) -> float:
    """The distance between two boxes [px] (0 when they overlap)."""
    return math.hypot(max(0.0, max(a.x0, b.x0) - min(a.x1, b.x1)), max(0.0, max(a.y0, b.y0) - min(a.y1, b.y1)))


TARGET_RGB = (0.77, 0.19, 0.19)  # the target's star and success circle (the end marker's red, darker)


def draw_targets(ax: Axes, points: Sequence[Sequence[float]], radius_m: float, *, legend: bool = True) -> None:
    """Each target point as a star inside a dashed circle of the success radius [m]: where success begins.

    Without it a path that stops `radius_m` short of an object looks like it fell short. One legend entry.
    """
    # deferred: matplotlib (about 0.3 s) loads only when a figure is drawn
    from matplotlib.patches import Circle

    for index, point in enumerate(points):
        x, y = float(point[0]), float(point[1])
        first = legend and index == 0
        ax.add_patch(
            Circle(
                (x, y),
                radius_m,
                fill=False,
                edgecolor=TARGET_RGB,
                linestyle="--",
                linewidth=1.1,
                zorder=5.2,
                label=f"success radius ({radius_m:g} m)" if first else None,
            )
        )
        ax.plot(x, y, "*", color=TARGET_RGB, ms=11, mec="white", mew=0.6, zorder=6.5, label="target" if first else None)


def place_point_labels(
    ax: Axes, items: Sequence[tuple[str, Sequence[float]]], *, fontsize: float, color: Any, avoid: Sequence[Any] = ()
) -> list[Any]:
    """Label points where no label meets another label, a text already on the axes or a box in `avoid`.

    Candidates go around each point on two rings; the first free one wins (else the least crowded).
    `avoid`: display-space boxes of markers (the start and end) that a label must not cover. Call it after
    the axes' limits are final.
    """
    # deferred: matplotlib (about 0.3 s) loads only when a figure is drawn
    from matplotlib import patheffects
    from matplotlib.transforms import Bbox

    ax.apply_aspect()
    renderer = ax.figure.canvas.get_renderer()  # type: ignore[attr-defined]
    px_per_pt = ax.figure.dpi / 72.0
    taken = [t.get_window_extent(renderer) for t in ax.texts if t.get_text()] + list(avoid)
    probe = ax.text(0.0, 0.0, "", fontsize=fontsize)
    placed = []
    for text, point in items:
        probe.set_text(text)
        size = probe.get_window_extent(renderer)
        w, h = size.width + 2 * _HALO_PT * px_per_pt, size.height + _HALO_PT * px_per_pt
        px, py = ax.transData.transform((float(point[0]), float(point[1])))
        best: tuple[int, Any, tuple[float, float]] | None = None
        for reach in (4.0, 4.0 + 1.3 * h, 4.0 + 2.6 * h):
            for dx, dy in ((1, 1), (1, -1), (-1, 1), (-1, -1), (1, 0), (-1, 0), (0, 1), (0, -1)):
                cx = px + dx * (reach + w / 2) if dx else px
                cy = py + dy * (reach + h / 2) if dy else py
                box = Bbox.from_extents(cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2)
                crowd = sum(box.overlaps(b) for b in taken)
                if best is None or crowd < best[0]:
                    best = (crowd, box, (cx - px, cy - py))
            if best is not None and best[0] == 0:
                break
        assert best is not None
        _, box, (ox, oy) = best
        placed.append(
            ax.annotate(
                text,
                (float(point[0]), float(point[1])),
                xytext=(ox / px_per_pt, oy / px_per_pt),
                textcoords="offset points",
                ha="center",
                va="center",
                fontsize=fontsize,
                color=color,
                zorder=7,
                path_effects=[patheffects.withStroke(linewidth=_HALO_PT, foreground="white")],
            )
        )
        taken.append(box)
    probe.remove()
    return placed


def _draw_start_poses(ax: Axes, scenario: Scenario, task: Task | None) -> None:
    """Numbered arrows for the start poses (all tasks' when `task` is None)."""
    tasks = [task] if task is not None else scenario.tasks
    length = 0.06 * max(scenario.bounds.x[1] - scenario.bounds.x[0], scenario.bounds.y[1] - scenario.bounds.y[0])
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
        if task is not None and task.kind == "target":
            draw_targets(ax, scenario.target_points(task), SUCCESS_RADIUS_M)
        title = scenario.name if task is None else f"{scenario.name} - {task.id}: {task.text}"
        ax.set_title(printable(title), fontsize=10)
        fig.tight_layout()
        fig.savefig(out, dpi=130)
    finally:
        plt.close(fig)
    return out


PixelMap = Callable[[float, float], tuple[int, int]]  # map point [m] -> image pixel (column, row)


def raster_scenario(
    scenario: Scenario, targets: Sequence[tuple[float, float]] = (), *, size_px: int = 480
) -> tuple[Any, PixelMap]:
    """The scenario's top view as an RGB array (for frames drawn many times a second), and map -> pixel.

    Drawn once with `draw_scenario`; callers copy the array and draw moving things on it with OpenCV.
    """
    # deferred: numpy (about 0.1 s) loads only when the scenario is rasterised
    import numpy as np

    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(size_px / 100, size_px / 100), dpi=100)
    bx, by = scenario.bounds.x, scenario.bounds.y
    try:
        draw_scenario(ax, scenario, labels=False)
        for x, y in targets:
            ax.plot([x], [y], marker="*", color="gold", markersize=14, markeredgecolor="k", zorder=20)
        ax.set_xlim(*bx)
        ax.set_ylim(*by)
        ax.set_axis_off()
        fig.subplots_adjust(0, 0, 1, 1)
        fig.canvas.draw()
        image = np.ascontiguousarray(np.asarray(fig.canvas.buffer_rgba())[:, :, :3])
        # The data -> display transform is affine: keep two corners' pixels so the figure can close.
        (x0, y0), (x1, y1) = ax.transData.transform([(bx[0], by[0]), (bx[1], by[1])])
    finally:
        plt.close(fig)
    height = image.shape[0]
    sx, sy = (x1 - x0) / (bx[1] - bx[0]), (y1 - y0) / (by[1] - by[0])

    def to_px(x: float, y: float) -> tuple[int, int]:
        return round(x0 + (x - bx[0]) * sx), round(height - (y0 + (y - by[0]) * sy))

    return image, to_px
