"""A scored decision's page: the scores stand where the raw reply would, and the content-free prompt is explained."""

from __future__ import annotations

import html
import re
from pathlib import Path

from llmnav.planners.base import drive_options
from llmnav.runs.runner import EpisodeSpec, run_episode
from llmnav.view.api import write_view
from llmnav.view.model import build_run_view


def test_scored_calls_show_their_scores(tmp_path: Path) -> None:
    spec = EpisodeSpec(
        scenario="corridor_a",
        task_text="Go to room 104",
        options=drive_options(planner="hybrid", max_iterations=6),
        backend="policy:keyword",
        out_dir=tmp_path / "run",
        plots=False,
    )
    run_episode(spec)
    calls = [c for step in build_run_view(tmp_path / "run").steps for c in step.calls]
    assert calls and all(c.scores for c in calls)
    free = [c for c in calls if c.content_free]
    assert free and len(free) < len(calls)  # the baseline prompts, told apart from the task's own
    assert any(" room 104" in [text for text, _, _ in c.scores] for c in calls)
    page = write_view(tmp_path / "run", tmp_path / "p.html").page.read_text(encoding="utf-8")
    assert "Raw reply:" not in page  # no empty reply box
    assert page.count('class="reply-scores"') == len(calls)
    assert page.count('class="hint content-free"') == len(free)
    text = html.unescape(re.sub(r"<[^>]+>", " ", page))
    assert 'content-free "N/A", on purpose' in " ".join(text.split())
