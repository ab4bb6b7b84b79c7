"""Every top view shows the target and its success radius; the trajectory figure's labels never collide."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parents[1] / "score"))
from score_fakes import config_for, tiny_scenario, write_run, write_scenario_file  # noqa: E402

from llmnav.runs.runlog import read_run  # noqa: E402
from llmnav.scoring.metrics import SUCCESS_RADIUS_M  # noqa: E402


def _run(tmp_path: Path) -> Path:
    """Short steps bunched up near the pellets, the last one ending beside them (where their name goes)."""
    poses = [[0, 0, 0], [3.6, 0, 0], [3.8, 0.1, 0], [4.0, 0.2, 0], [4.2, 0.3, 0], [4.3, 0.45, 0.3]]
    return write_run(tmp_path / "run", config_for("T1", start_pose_index=1), poses, summary=True)


def test_trajectory_figure_has_target_radius_and_clear_labels(tmp_path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle
    from matplotlib.text import Text

    from llmnav.reporting.trajectory import draw_record

    scenario = tiny_scenario()
    task = scenario.task("T1")
    fig, ax = plt.subplots(figsize=(8.0, 8.0), dpi=120)
    try:
        draw_record(ax, read_run(_run(tmp_path)), scenario, task)
        fig.canvas.draw()
        renderer = fig.canvas.get_renderer()
        (target,) = scenario.target_points(task)
        circles = [p for p in ax.patches if isinstance(p, Circle)]
        assert any(c.center == tuple(target) and c.radius == SUCCESS_RADIUS_M for c in circles)
        assert any(line.get_marker() == "*" and list(line.get_xydata()[0]) == list(target) for line in ax.lines)
        texts = [t for t in ax.texts if t.get_text()]
        assert {"pile of pellets", "1", "2"} <= {t.get_text() for t in texts}
        boxes = [(t.get_text(), Text.get_window_extent(t, renderer)) for t in texts]
        for i, (a_text, a) in enumerate(boxes):
            for b_text, b in boxes[i + 1 :]:
                assert not a.overlaps(b), (a_text, b_text)
        ends = [line for line in ax.lines if line.get_label() in ("end", "start")]
        assert len(ends) == 2
        for marker in ends:
            box = marker.get_window_extent(renderer)
            for text, label_box in boxes:
                assert not box.overlaps(label_box), (marker.get_label(), text)
    finally:
        plt.close(fig)


def test_page_and_video_maps_show_the_target(tmp_path: Path) -> None:
    import numpy as np

    from llmnav.reporting.topview import TARGET_RGB
    from llmnav.view.basemap import draw_base_map
    from llmnav.view.model import build_run_view

    scenario = tiny_scenario()
    (target,) = scenario.target_points(scenario.task("T1"))
    base = draw_base_map(scenario, 600, 600, targets=[target], radius_m=SUCCESS_RADIUS_M)
    plain = draw_base_map(scenario, 600, 600)
    x, y = base.to_px(*target)
    star = base.pixels[y - 2 : y + 3, x - 2 : x + 3].reshape(-1, 3).astype(int)
    red = np.array([round(255 * c) for c in reversed(TARGET_RGB)])  # BGR
    assert (np.abs(star - red).sum(axis=1) < 60).any()
    rx, _ = base.to_px(target[0] - SUCCESS_RADIUS_M, target[1])  # the circle's left edge
    ring = (base.pixels[y - 30 : y + 30, rx - 2 : rx + 3] != plain.pixels[y - 30 : y + 30, rx - 2 : rx + 3]).any(axis=2)
    assert ring.sum() > 10  # dashes of the circle cross the row through the target
    # and the run page and the video draw it: their view of a run knows its targets
    config = config_for("T1", scenario_file=write_scenario_file(tmp_path / "tiny.yaml"))
    view = build_run_view(write_run(tmp_path / "r", config, [[0, 0, 0]], summary=True))
    assert view.targets == [tuple(target)] and view.success_radius_m == SUCCESS_RADIUS_M


def test_page_map_names_stay_clear_of_the_end_marker() -> None:
    """The run ended just above the pellets, where their name would go: the name moves, the marker stays clear."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.text import Text
    from matplotlib.transforms import Bbox

    from llmnav.view.basemap import AXES_BOX, MARKER_PX, draw_map

    scenario = tiny_scenario()
    end = (5.0, 0.8)
    for markers, clear in (((), False), ((end,), True)):
        fig = plt.figure(figsize=(6.0, 6.0), dpi=100)
        ax = fig.add_axes(AXES_BOX)
        try:
            draw_map(ax, scenario, markers=markers)
            fig.canvas.draw()
            renderer = fig.canvas.get_renderer()
            px, py = ax.transData.transform(end)
            marker = Bbox.from_extents(px - MARKER_PX, py - MARKER_PX, px + MARKER_PX, py + MARKER_PX)
            (label,) = [t for t in ax.texts if t.get_text() == "pile of pellets"]
            assert Text.get_window_extent(label, renderer).overlaps(marker) is not clear
        finally:
            plt.close(fig)
