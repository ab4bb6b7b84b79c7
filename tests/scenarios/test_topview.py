"""Top views: draw_scenario puts every part of the world on the axes; plot_scenario writes a PNG."""

from __future__ import annotations

from pathlib import Path

import pytest

from llmnav.reporting.topview import draw_scenario, plot_scenario
from llmnav.world.scenario import load_scenario


@pytest.mark.parametrize("name", ["factory", "corridor_c", "maze_arena"])
def test_draw_scenario_draws_every_part(name: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scenario = load_scenario(name)
    fig, ax = plt.subplots()
    try:
        draw_scenario(ax, scenario)
        # floor + corridors + walls + obstacles + objects, one patch each
        parts = (
            1
            + len(scenario.corridors)
            + len(scenario.walls)
            + len(scenario.obstacles)
            + len(scenario.objects)
        )
        assert len(ax.patches) == parts
        texts = {t.get_text() for t in ax.texts}
        assert {o.label for o in scenario.objects} <= texts
        x0, x1 = ax.get_xlim()
        assert x0 <= scenario.bounds.x[0] and x1 >= scenario.bounds.x[1]
    finally:
        plt.close(fig)
    fig, ax = plt.subplots()
    try:
        draw_scenario(ax, scenario, labels=False)
        assert len(ax.texts) == 0 and len(ax.patches) == parts
    finally:
        plt.close(fig)


def test_plot_scenario_writes_pngs_with_start_arrows(tmp_path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    scenario = load_scenario("factory")
    task = scenario.task("T3")
    out = plot_scenario(scenario, tmp_path / "sub" / "t3.png", task=task)
    assert out == tmp_path / "sub" / "t3.png" and out.read_bytes()[:4] == b"\x89PNG"
    whole = plot_scenario(load_scenario("corridor_c"), tmp_path / "corridor_c.png")
    assert whole.stat().st_size > 10_000
