"""`llmnav score --plot`: long condition labels are wrapped under their bars, never into each other."""

from __future__ import annotations

from pathlib import Path

from llmnav.reporting.charts import condition_figure
from llmnav.runs.folders import Run


def test_long_labels_never_overlap(tmp_path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups = []
    for k in range(6):
        label = f"backend=openai:http://127.0.0.1:80{k:02d}/v1/a-rather-long-model-name-{k}, prompt=full"
        runs = [Run(tmp_path / f"r{k}{i}", {"score": 0.1 * k + 0.05 * i, "success": i == 1}, {}) for i in range(2)]
        groups.append((label, runs))
    fig = condition_figure("T1", groups, ["backend", "prompt"])
    try:
        fig.canvas.draw()
        renderer = fig.canvas.get_renderer()
        page = fig.bbox
        for ax in fig.axes:
            labels = [t for t in ax.get_xticklabels() if t.get_text()]
            assert len(labels) == 6
            boxes = [t.get_window_extent(renderer) for t in labels]
            for i, a in enumerate(boxes):
                assert page.x0 <= a.x0 and a.x1 <= page.x1 and page.y0 <= a.y0, labels[i].get_text()
                for b in boxes[i + 1 :]:
                    assert not a.overlaps(b)
            assert all(t.get_rotation() == 0 for t in labels)
        rate_axis = fig.axes[1]
        lows = [line for line in rate_axis.lines if line.get_marker() == "_"]  # the error bars' caps
        assert all(0.0 <= y <= 1.0 for line in lows for y in line.get_ydata())  # Wilson: inside [0, 1]
    finally:
        plt.close(fig)
