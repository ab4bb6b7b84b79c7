"""The top view's object labels: none overlaps another, each has a halo and sits inside the map."""

from __future__ import annotations

import pytest

from llmnav.reporting.topview import draw_scenario
from llmnav.view.basemap import AXES_BOX, DPI, page_size
from llmnav.world.scenario import list_scenarios, load_scenario

SCENARIOS = list_scenarios()


def _labels(name: str):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scenario = load_scenario(name)
    width, height = page_size(scenario)  # the size the viewer draws the map at
    fig = plt.figure(figsize=(width / DPI, height / DPI), dpi=DPI)
    ax = fig.add_axes(AXES_BOX)
    draw_scenario(ax, scenario)
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    texts = [t for t in ax.texts if t.get_text()]
    return scenario, fig, ax, texts, renderer


def _box(text, renderer):
    from matplotlib.text import Text

    return Text.get_window_extent(text, renderer)  # the text alone (an annotation's own extent adds its leader)


@pytest.mark.parametrize("name", SCENARIOS)
def test_labels_do_not_overlap_and_have_a_halo(name: str) -> None:
    import matplotlib.pyplot as plt
    from matplotlib import patheffects

    scenario, fig, ax, texts, renderer = _labels(name)
    try:
        assert {t.get_text() for t in texts} == {o.label for o in scenario.objects}  # every name is shown
        boxes = [_box(t, renderer) for t in texts]
        frame = ax.get_window_extent(renderer)
        for i, a in enumerate(boxes):
            assert frame.x0 <= a.x0 and a.x1 <= frame.x1 and frame.y0 <= a.y0 and a.y1 <= frame.y1, texts[i]
            for j in range(i + 1, len(boxes)):
                assert not a.overlaps(boxes[j]), (texts[i].get_text(), texts[j].get_text())
        for text in texts:
            assert text.get_fontsize() >= 7.5
            strokes = [e for e in text.get_path_effects() if isinstance(e, patheffects.withStroke)]
            assert strokes and strokes[0]._gc["foreground"] == "white"  # the contrasting halo
    finally:
        plt.close(fig)


def test_factory_cabinets_are_told_apart() -> None:
    # the case that overlapped: "open cabinet" ran into "closed cabinet"
    import matplotlib.pyplot as plt

    _, fig, _, texts, renderer = _labels("factory")
    try:
        by_text = {t.get_text(): _box(t, renderer) for t in texts}
        assert not by_text["open cabinet"].overlaps(by_text["closed cabinet"])
    finally:
        plt.close(fig)
