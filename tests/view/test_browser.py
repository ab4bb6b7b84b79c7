"""The pages in a real browser: Debian's Chromium, headless, driven through Playwright (no browser
download). One entry per decision, selecting step k (click, marker, arrow keys) shows step k's reply, no
console errors or dialogs (hostile replies must not run), and a screenshot that is not blank.

Skipped, with the reason, where Chromium or the Playwright package is missing; CI installs Chromium.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from llmnav.view.api import write_view
from llmnav.view.shot import BROWSER_FLAGS, find_browser

from .logs import decisions, last_reply

# The flags `llmnav view --screenshot` starts Chromium with (no network, no first-run work).
CHROMIUM_FLAGS = list(BROWSER_FLAGS)


@pytest.fixture(scope="module")
def browser(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Any]:
    sync_api = pytest.importorskip("playwright.sync_api", reason="the playwright package is not installed")
    executable = find_browser()
    if executable is None:
        pytest.skip("no Chromium at /usr/bin/chromium or on PATH (CI installs Debian's chromium)")
    profile = tmp_path_factory.mktemp("chromium-profile")  # a fresh --user-data-dir
    with sync_api.sync_playwright() as playwright:
        context = playwright.chromium.launch_persistent_context(
            str(profile),
            executable_path=executable,
            headless=True,
            args=CHROMIUM_FLAGS,
            viewport={"width": 1400, "height": 900},
        )
        try:
            yield context
        finally:
            context.close()


class Page:
    """A page opened from disk, with everything the console said and every dialog it tried to open."""

    def __init__(self, context: Any, path: Path) -> None:
        self.problems: list[str] = []
        self.page = context.new_page()
        self.page.on(
            "console", lambda m: m.type in ("error", "warning") and self.problems.append(f"{m.type}: {m.text}")
        )
        self.page.on("pageerror", lambda e: self.problems.append(f"pageerror: {e}"))
        self.page.on("dialog", lambda d: (self.problems.append(f"dialog: {d.message}"), d.dismiss()))
        self.page.goto(path.resolve().as_uri())

    def selected_reply(self) -> str:
        replies = self.page.locator("section.step.selected pre.reply")
        return replies.nth(replies.count() - 1).inner_text() if replies.count() else ""

    def selected_index(self) -> int:
        return int(self.page.locator("section.step.selected").get_attribute("data-step"))

    def assert_not_blank(self, out: Path) -> None:
        self.page.screenshot(path=str(out))
        assert_not_blank(out)


def assert_not_blank(png: Path) -> None:
    import cv2
    import numpy as np

    pixels = cv2.imread(str(png))
    assert pixels is not None and pixels.shape[0] > 100
    colours = np.unique(pixels.reshape(-1, 3)[::7], axis=0)
    assert pixels.std() > 20 and len(colours) > 50, "the screenshot is (nearly) blank"


@pytest.mark.parametrize("kind", ["stepwise", "hybrid", "fsm", "waypoints", "killed"])
def test_run_page_in_chromium(browser, runs, tmp_path, kind):
    path = write_view(runs[kind], tmp_path / f"{kind}.html").page
    keys = decisions(runs[kind])
    view = Page(browser, path)
    buttons = view.page.locator("nav.steps button[data-step]")
    assert buttons.count() == len(keys)
    assert view.selected_index() == 0
    for k in sorted({0, len(keys) // 2, len(keys) - 1}):
        buttons.nth(k).click()
        assert view.selected_index() == k
        assert view.page.locator("section.step:visible").count() == 1
        expected = last_reply(runs[kind], keys[k])
        if expected is not None:
            assert view.selected_reply().strip() == expected.strip()
    # keyboard: ← and → walk through the decisions
    buttons.nth(0).click()
    view.page.keyboard.press("ArrowRight")
    assert view.selected_index() == min(1, len(keys) - 1)
    view.page.keyboard.press("ArrowLeft")
    assert view.selected_index() == 0
    # a marker on the map selects its decision
    markers = view.page.locator("svg.map .marker")
    if markers.count() > 1:
        last = markers.nth(markers.count() - 1)
        last.dispatch_event("click")
        assert view.selected_index() == int(last.get_attribute("data-step"))
    view.assert_not_blank(tmp_path / f"{kind}.png")
    assert view.problems == []


def test_sweep_page_in_chromium_links_to_run_pages(browser, sweep, tmp_path):
    path = write_view(sweep).page
    view = Page(browser, path)
    links = view.page.locator("table.runs a")
    assert links.count() == 4
    assert view.page.locator("table.success-map").count() == 2
    view.assert_not_blank(tmp_path / "sweep.png")
    links.nth(0).click()
    view.page.wait_for_load_state()
    assert view.page.locator("nav.steps button[data-step]").count() >= 1
    assert view.problems == []


def test_view_screenshot_opens_the_asked_step(browser, runs, tmp_path):
    """`llmnav view --screenshot` (how the README's picture is made) with Chromium's own --screenshot."""
    import cv2
    import numpy as np

    from llmnav.view.shot import screenshot

    page = write_view(runs["stepwise"], tmp_path / "p.html").page
    first = screenshot(page, tmp_path / "first.png", width=1280, height=800)
    last = screenshot(page, tmp_path / "last.png", step=len(decisions(runs["stepwise"])), width=1280, height=800)
    assert_not_blank(first)
    a, b = cv2.imread(str(first)), cv2.imread(str(last))
    assert a.shape == b.shape == (800, 1280, 3)
    assert np.abs(a.astype(int) - b.astype(int)).mean() > 1.0  # another decision is shown


def test_sweep_chart_labels_never_overlap(browser, tmp_path):
    """Long condition labels (backend URLs) are wrapped in their own rows: no two label boxes meet, none is cut."""
    import sys

    sys.path.insert(0, str(Path(__file__).parents[1] / "score"))
    from score_fakes import config_for, write_run

    root = tmp_path / "long-labels"
    for k in range(6):
        backend = f"openai:http://127.0.0.1:80{k:02d}/v1/a-rather-long-model-name-{k}-instruct-q4_k_m"
        write_run(root / f"r{k}", config_for("T1", backend=backend), [[0, 0, 0], [1.0 + k * 0.7, 0, 0]], summary=True)
    view = Page(browser, write_view(root).page)
    view.page.set_viewport_size({"width": 760, "height": 900})
    labels = view.page.locator("table.bars th.bar-label")
    assert labels.count() == 6
    boxes = [labels.nth(i).bounding_box() for i in range(6)]
    for i, a in enumerate(boxes):
        for b in boxes[i + 1 :]:
            apart = a["y"] + a["height"] <= b["y"] or b["y"] + b["height"] <= a["y"]
            apart = apart or a["x"] + a["width"] <= b["x"] or b["x"] + b["width"] <= a["x"]
            assert apart, (a, b)
    # every label whole (wrapped, not cut or spilling into the bars beside it)
    spill = labels.evaluate_all(
        "els => els.filter(e => e.scrollWidth > e.clientWidth + 1"
        " || e.getBoundingClientRect().right > e.nextElementSibling.getBoundingClientRect().left + 0.5).length"
    )
    assert spill == 0
    texts = [labels.nth(i).inner_text() for i in range(6)]
    assert all("a-rather-long-model-name" in t for t in texts)
    assert view.problems == []
