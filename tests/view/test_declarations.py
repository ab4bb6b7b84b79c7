"""The run page names no planner: how it groups and marks decisions is what the run's planner declares
(looked up through the registry), and for a planner that is not installed, what the log itself shows."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from llmnav.view.model import build_run_view
from llmnav.view.page import run_page

TURNS = """
from typing import ClassVar
from llmnav.core.declarations import Declarations
from llmnav.planners.base import EpisodeContext, EpisodeOutcome, Planner


class TurnsPlanner(Planner):
    name: ClassVar[str] = "turns"
    declares: ClassVar[Declarations] = Declarations(decision_noun="Turn", asks_model_every_decision=True)

    def run(self, ctx: EpisodeContext) -> EpisodeOutcome:
        return EpisodeOutcome("completed", "nothing to do")
"""


def _as_planner(run: Path, out: Path, planner: str) -> Path:
    """A copy of `run` whose config line names `planner`."""
    shutil.copytree(run, out, ignore=shutil.ignore_patterns("view.html"))
    lines = (out / "run.jsonl").read_text(encoding="utf-8").split("\n")
    config = json.loads(lines[0])
    config["planner"] = config["options"]["planner"] = planner
    (out / "run.jsonl").write_text("\n".join([json.dumps(config), *lines[1:]]), encoding="utf-8")
    return out


def _decisions(run: Path) -> list[tuple[str, list[str]]]:
    return [(s.label, s.missing) for s in build_run_view(run).steps]


@pytest.mark.parametrize("kind", ["stepwise", "killed", "fsm", "waypoints"])
def test_a_run_whose_planner_is_not_installed_is_read_from_its_log(runs, tmp_path, kind):
    ghost = _as_planner(runs[kind], tmp_path / kind, "not-installed-here")
    installed, fallback = build_run_view(runs[kind]), build_run_view(ghost)
    assert fallback.declared.velocity_view == installed.declared.velocity_view
    assert (fallback.profile is None) == (installed.profile is None)
    labels = [s.label.replace("Leg ", "Step ") for s in installed.steps]  # the noun is the planner's word
    assert [s.label for s in fallback.steps] == labels
    assert [s.missing for s in fallback.steps] == [s.missing for s in installed.steps]
    page = run_page(ghost)
    assert page.count('<section class="step" ') == len(installed.steps)
    if kind == "fsm":
        assert 'alt="FSM command profile' in page and "Suggestion 1" in page


def test_a_third_party_planner_names_its_decisions(runs, tmp_path, install_planner):
    install_planner("turns", "turns_view:TurnsPlanner", TURNS)
    run = _as_planner(runs["killed"], tmp_path / "turns", "turns")
    steps = build_run_view(run).steps
    assert [s.label for s in steps] == [f"Turn {s.step}" for s in steps]
    assert any("no action logged" in m for s in steps for m in s.missing)
