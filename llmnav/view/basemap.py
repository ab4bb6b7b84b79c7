"""The top view both the page and the video draw on: `llmnav.reporting.topview.draw_scenario` as a picture.

The map is drawn once with matplotlib and kept with the affine mapping of its axes, world [m] → pixel
(x right, y down), so the page's SVG layers and the video's robot land exactly on it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import numpy as np

    from llmnav.world.scenario import Scenario

DPI = 100
AXES_BOX = (0.08, 0.08, 0.9, 0.88)  # left, bottom, width, height of the axes in the figure
MARGIN_M = 1.0  # [m] around the trajectory when there is no scenario to frame it


@dataclass
class BaseMap:
    """A drawn top view and its world → pixel mapping: px = sx·x + ox, py = sy·y + oy."""

    pixels: np.ndarray  # BGR
    sx: float
    ox: float
    sy: float
    oy: float

    @property
    def width(self) -> int:
        """Pixels."""
        return int(self.pixels.shape[1])

    @property
    def height(self) -> int:
        """Pixels."""
        return int(self.pixels.shape[0])

    @property
    def metre_px(self) -> float:
        """Pixels per metre."""
        return abs(self.sx)

    def to_px(self, x: float, y: float) -> tuple[int, int]:
        """Pixel of a world point."""
        return (round(self.sx * x + self.ox), round(self.sy * y + self.oy))

    def png(self) -> bytes:
        """The picture as PNG bytes."""
        # deferred: OpenCV (about 0.13 s) loads only when a picture is encoded
        import cv2

        ok, encoded = cv2.imencode(".png", self.pixels, [cv2.IMWRITE_PNG_COMPRESSION, 9])
        return encoded.tobytes() if ok else b""


def draw_base_map(
    scenario: Scenario | None,
    width_px: int,
    height_px: int,
    *,
    oracle: Sequence[Sequence[float]] | None = None,
    trajectory: Sequence[Sequence[float]] = (),
    faint_paths: bool = False,
    targets: Sequence[Sequence[float]] = (),
    radius_m: float = 2.5,
    markers: Sequence[Sequence[float]] = (),
) -> BaseMap:
    """The scenario's top view (or an empty frame around the trajectory), optionally with the paths.

    `targets`: points [m] drawn as stars inside a dashed circle of `radius_m` [m], the success radius.
    `markers`: points [m] where the page draws a marker of MARKER_PX (the run's start and end): object
    names are placed clear of them.
    """
    # deferred: OpenCV and matplotlib (about 0.4 s) load only when a map is drawn
    import cv2
    import matplotlib

    matplotlib.use("Agg")
    # deferred with matplotlib: pyplot comes after the Agg backend is chosen
    import matplotlib.pyplot as plt
    import numpy as np

    fig = plt.figure(figsize=(width_px / DPI, height_px / DPI), dpi=DPI)
    ax = fig.add_axes(AXES_BOX)
    try:
        draw_map(ax, scenario, oracle=oracle, trajectory=trajectory, faint_paths=faint_paths, targets=targets,
                 radius_m=radius_m, markers=markers)  # fmt: skip
        fig.canvas.draw()
        rgba = np.asarray(fig.canvas.buffer_rgba())  # type: ignore[attr-defined]
        # Display coordinates have y up from the bottom; image rows go down from the top.
        (x0, y0), (x1, y1) = ax.transData.transform([(0.0, 0.0), (1.0, 1.0)])
        rows = rgba.shape[0]
        pixels = cv2.cvtColor(rgba, cv2.COLOR_RGBA2BGR)
        return BaseMap(pixels, float(x1 - x0), float(x0), float(-(y1 - y0)), float(rows - y0))
    finally:
        plt.close(fig)


MARKER_PX = 12.0  # [px] half the size of the page's start and end markers, with a little room


def draw_map(
    ax: Any,
    scenario: Scenario | None,
    *,
    oracle: Sequence[Sequence[float]] | None = None,
    trajectory: Sequence[Sequence[float]] = (),
    faint_paths: bool = False,
    targets: Sequence[Sequence[float]] = (),
    radius_m: float = 2.5,
    markers: Sequence[Sequence[float]] = (),
) -> None:
    """`draw_base_map`'s drawing on an axes (the object names placed last, clear of targets and markers)."""
    # deferred: matplotlib and the top view (with pydantic and yaml) load only when a map is drawn
    from matplotlib.transforms import Bbox

    from llmnav.reporting.topview import draw_scenario, draw_targets, label_fontsize, place_labels

    if scenario is not None:
        draw_scenario(ax, scenario, labels=False)
    else:
        ax.set_aspect("equal")
        points = list(trajectory) or [(0.0, 0.0)]
        xs, ys = [float(p[0]) for p in points], [float(p[1]) for p in points]
        ax.set_xlim(min(xs) - MARGIN_M, max(xs) + MARGIN_M)
        ax.set_ylim(min(ys) - MARGIN_M, max(ys) + MARGIN_M)
        ax.grid(True, linewidth=0.3, alpha=0.4)
    if targets:
        draw_targets(ax, targets, radius_m, legend=False)
    if faint_paths and oracle:
        ax.plot([p[0] for p in oracle], [p[1] for p in oracle], "--", color="0.35", lw=1.2, zorder=5.5)
    if faint_paths and trajectory:
        ax.plot([p[0] for p in trajectory], [p[1] for p in trajectory], color="tab:blue", lw=1.0, alpha=0.35)
    ax.tick_params(labelsize=7)
    ax.xaxis.label.set_fontsize(8)
    ax.yaxis.label.set_fontsize(8)
    if scenario is not None:
        ax.apply_aspect()
        renderer = ax.figure.canvas.get_renderer()
        avoid = [line.get_window_extent(renderer) for line in ax.lines if line.get_marker() == "*"]
        for point in markers:
            px, py = ax.transData.transform((float(point[0]), float(point[1])))
            avoid.append(Bbox.from_extents(px - MARKER_PX, py - MARKER_PX, px + MARKER_PX, py + MARKER_PX))
        place_labels(ax, scenario, fontsize=label_fontsize(scenario), avoid=avoid)


def page_size(scenario: Scenario | None, width_px: int = 720) -> tuple[int, int]:
    """A picture size that fits the map's aspect ratio (with room for the axes)."""
    if scenario is None:
        return width_px, round(width_px * 0.75)
    (x0, x1), (y0, y1) = scenario.bounds.x, scenario.bounds.y
    aspect = (y1 - y0) / max(x1 - x0, 1e-6)
    height = aspect * width_px * AXES_BOX[2] / AXES_BOX[3] + 20
    return width_px, int(min(max(height, 260), 1100))
