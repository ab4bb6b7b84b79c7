"""The hybrid planner deciding by scored option texts: the decision rule, a run end to end, replay, fallback."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from llmnav.backends.replay import write_script
from llmnav.cli import app
from llmnav.core.chat import ContinuationScore, ScoreRequest, ScoreResult
from llmnav.planners.base import drive_options
from llmnav.planners.hybrid.scoring import (
    CONTENT_FREE_TASK,
    Candidate,
    ScoredChooser,
    ScoringConfig,
)
from llmnav.runs.runlog import read_run
from llmnav.runs.runner import EpisodeSpec, run_episode


class FakeContext:
    """What `ScoredChooser` reads of an episode context: `score`, answered from fixed log-probabilities."""

    def __init__(self, task_scores: dict[str, float], free: float = -5.0) -> None:
        self.task_scores = task_scores
        self.free = free
        self.requests: list[ScoreRequest] = []

    def score(self, request: ScoreRequest, step: int | None) -> ScoreResult:
        self.requests.append(request)
        content_free = f"Task: {CONTENT_FREE_TASK}\n" in request.prefix
        values = [
            self.free if content_free else self.task_scores.get(c.strip(), self.free) for c in request.continuations
        ]
        return ScoreResult(tuple(ContinuationScore(v, 1) for v in values), 0.0, "fake")


def chooser(scores: dict[str, float], *, mapped: bool = False) -> tuple[ScoredChooser, FakeContext]:
    ctx = FakeContext(scores)
    return ScoredChooser(ctx, "some task", mapped=mapped), ctx  # type: ignore[arg-type]


MENU = [
    Candidate(1, "landmark", ("table",), 3.0),
    Candidate(2, "landmark", ("stairs",), 9.0),
    Candidate(3, "frontier", (), 4.0),
    Candidate(4, "scan"),
    Candidate(5, "complete"),
]


def test_a_turning_task_turns_once_then_finishes() -> None:
    choose, _ = chooser({"turn around on the spot": 0.0, "drive to something": -4.0})
    assert choose.choose(MENU, turned=False, step=1).number == 4
    assert choose.choose([c for c in MENU if c.kind != "scan"], turned=True, step=2).number == 5


def test_a_going_task_looks_around_first_without_a_map_but_not_with_one() -> None:
    scores = {"drive to something": 0.0, "stairs": 3.0}
    assert chooser(scores)[0].choose(MENU, turned=False, step=1).rule == "look around before choosing"
    assert chooser(scores, mapped=True)[0].choose(MENU, turned=False, step=1).number == 2


def test_a_sure_target_is_taken_and_an_unsure_one_explored_first() -> None:
    sure, _ = chooser({"drive to something": 0.0, "stairs": 5.0 + 6.0, "table": 1.0})  # PMI 11 vs 6
    assert sure.choose(MENU, turned=True, step=2).number == 2
    unsure, _ = chooser({"drive to something": 0.0, "stairs": -5.0 + 3.0, "table": -5.0 + 0.5})
    decision = unsure.choose(MENU, turned=True, step=2)
    assert decision.number == 3 and "explore" in decision.rule
    assert decision.scores == pytest.approx({"table": 0.5, "stairs": 3.0})


def test_an_unsure_target_is_taken_once_the_exploration_budget_is_spent() -> None:
    choose, _ = chooser({"drive to something": 0.0, "stairs": -5.0 + 3.0})
    choose.cfg = ScoringConfig(explore_budget=1)
    assert choose.choose(MENU, turned=True, step=2).number == 3
    assert choose.choose(MENU, turned=True, step=3).number == 2


def test_with_nothing_worth_taking_the_search_goes_on_past_the_budget() -> None:
    """The budget bounds exploring before an unsure target is taken; below min_pmi there is none to take."""
    choose, _ = chooser({"drive to something": 0.0, "stairs": -5.0 - 2.0, "table": -5.0 - 1.0})
    choose.cfg = ScoringConfig(explore_budget=1)
    for step in (2, 3, 4):
        decision = choose.choose(MENU, turned=True, step=step)
        assert decision.number == 3 and not decision.not_found, decision
    without_frontier = [c for c in MENU if c.kind != "frontier"]
    assert choose.choose(without_frontier, turned=True, step=5).number == 4  # then a look where none was made


def test_an_exploration_cut_short_by_something_new_is_not_counted_against_the_budget() -> None:
    # `explored` counts explorations carried to their end; one stopped because something new came into view
    # hands the decision back and leaves the budget as it was.
    rejected = {"drive to something": 0.0, "stairs": -5.0 - 10.0, "table": -5.0 - 10.0}
    choose, _ = chooser(rejected)
    choose.cfg = ScoringConfig(explore_budget=1)
    assert choose.choose(MENU, turned=True, step=2, explored=0).number == 3
    assert choose.choose(MENU, turned=True, step=3, explored=0).number == 3  # the first was cut short


def test_equal_relevance_goes_to_the_nearer_landmark() -> None:
    menu = [Candidate(1, "landmark", ("oil barrel",), 7.0), Candidate(2, "landmark", ("oil barrel",), 2.0), MENU[4]]
    choose, _ = chooser({"drive to something": 0.0, "oil barrel": 9.0}, mapped=True)
    assert choose.choose(menu, turned=True, step=1).number == 2


def test_at_an_unsure_target_it_looks_once_more_then_finishes() -> None:
    here = [Candidate(1, "landmark", ("table",), 3.0), Candidate(2, "scan"), Candidate(3, "complete", ("stairs",))]
    choose, _ = chooser({"drive to something": 0.0, "stairs": -5.0 + 3.0, "table": -5.0 + 0.5})
    assert choose.choose(here, turned=True, step=4).number == 2
    assert choose.choose([here[0], here[2]], turned=True, step=5).number == 3


def test_nothing_fitting_and_nothing_left_to_see_ends_not_found_instead_of_finishing_at_a_rejected_place() -> None:
    # The robot stands at a washing machine the task makes less likely; no frontier, no look left.
    here = [Candidate(1, "landmark", ("sofa",), 4.0), Candidate(2, "complete", ("washing machine",))]
    choose, _ = chooser({"drive to something": 0.0, "washing machine": -5.0 - 10.0, "sofa": -5.0 + 0.5})
    decision = choose.choose(here, turned=True, step=6)
    assert decision.not_found and decision.rule.startswith("not found")
    assert decision.to_log()["not_found"] is True
    # Above min_pmi the same place is a finish, not a give-up.
    sure, _ = chooser({"drive to something": 0.0, "washing machine": -5.0 + 2.0})
    finished = sure.choose(here, turned=True, step=6)
    assert finished.number == 2 and not finished.not_found


def test_nothing_seen_and_nothing_left_to_explore_is_not_found() -> None:
    choose, _ = chooser({"drive to something": 0.0})
    decision = choose.choose([Candidate(1, "complete")], turned=True, step=3)
    assert decision.not_found


def test_each_text_is_scored_once_per_episode() -> None:
    choose, ctx = chooser({"drive to something": 0.0, "stairs": 9.0}, mapped=True)
    choose.choose(MENU, turned=True, step=1)
    asked = len(ctx.requests)
    choose.choose(MENU, turned=True, step=2)
    assert len(ctx.requests) == asked  # nothing new on the menu: nothing scored again
    scored = [c.strip() for r in ctx.requests for c in r.continuations]
    assert sorted(scored) == sorted(["drive to something", "turn around on the spot", "table", "stairs"] * 2)


# --- end to end ------------------------------------------------------------------------------
def _drive(tmp_path: Path, name: str, backend: str, **options: Any) -> dict[str, Any]:
    spec = EpisodeSpec(
        scenario="corridor_a",
        task_text="Go to room 104",
        options=drive_options(max_iterations=6, **options),
        backend=backend,
        out_dir=tmp_path / name,
        plots=False,
    )
    return run_episode(spec)


def test_keyword_scores_drive_to_the_room_and_a_strict_replay_repeats_it(tmp_path: Path) -> None:
    summary = _drive(tmp_path, "live", "policy:keyword")
    assert summary["success"] and summary["outcome"] == "completed", summary
    record = read_run(tmp_path / "live")
    assert [e["decide"] for e in record.of_type("planner")] == ["score"]
    decisions = record.of_type("decision")
    assert decisions and decisions[0]["pmi"]["room 104"] == max(decisions[0]["pmi"].values())
    calls = record.of_type("llm_call")
    assert calls and all(c["purpose"] == "score" for c in calls)
    replayed = _drive(tmp_path, "replay", f"replay:{tmp_path / 'live'}")
    assert replayed["final_pose"] == summary["final_pose"]
    assert [e["decide"] for e in read_run(tmp_path / "replay").of_type("planner")] == ["score"]


def test_first_by_position_does_not_reach_the_room(tmp_path: Path) -> None:
    """The floor: scores that say nothing about the task (the first option always highest)."""
    summary = _drive(tmp_path, "first", "policy:first")
    assert not summary["success"], summary


def test_a_backend_that_cannot_score_falls_back_to_generation_and_says_so(tmp_path: Path) -> None:
    spec = write_script(tmp_path / "script", [json.dumps({"option": 1, "reasoning": "x"})] * 6, purpose="choice")
    _drive(tmp_path, "fallback", f"replay:{spec}")
    record = read_run(tmp_path / "fallback")
    assert [(e["decide"], e["requested"]) for e in record.of_type("planner")] == [("generate", "auto")]
    assert record.of_type("llm_call") and not record.of_type("decision")


def test_decide_score_with_a_backend_that_cannot_score_is_bad_input(tmp_path: Path) -> None:
    spec = write_script(tmp_path / "script", ['{"option": 1}'], purpose="choice")
    out = tmp_path / "never"
    result = CliRunner().invoke(
        app,
        ["drive", "--task", "Go to room 101", "--decide", "score", "--backend", f"replay:{spec}", "--out", str(out)],
    )
    assert result.exit_code == 2, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and "cannot score" in lines[0] and "replay:" in lines[0], result.output
    assert not out.exists()


def test_the_page_shows_each_decisions_scores_as_bars(tmp_path: Path) -> None:
    import html as html_lib
    import re

    from llmnav.view.api import write_view

    _drive(tmp_path, "scored", "policy:keyword")
    page = write_view(tmp_path / "scored").page.read_text(encoding="utf-8")
    decisions = read_run(tmp_path / "scored").of_type("decision")
    captions = re.findall(r"<caption>Scored decision: ([^<]*) —", page)
    assert [html_lib.unescape(c) for c in captions] == [d["rule"] for d in decisions]
    first = decisions[0]["pmi"]
    bars = re.findall(r'aria-label="([^"]+) ([+-]\d+\.\d)"><rect', page)
    assert len(bars) == sum(len(d["pmi"]) for d in decisions)
    assert {name: float(value) for name, value in bars[: len(first)]} == pytest.approx(
        {name: round(value, 1) for name, value in first.items()}
    )
    assert bars[0][0] == max(first, key=first.__getitem__)  # the best first, drawn in the highlight colour


def test_a_leg_the_motion_layer_refuses_is_a_veto_and_near_the_target_counts_as_arrival(tmp_path: Path) -> None:
    """Factory T8 from pose 4: the boxes' goal point hugs them and the guarded layer refuses a last leg.

    (Run on odometry alone: the localizer's corrected legs are no longer refused here. Which start pose
    meets a refusal moves with the planner's exploration.)

    Before, the planner passed over the refusal ("stopped 0.4 m short"), chose the same trip again and
    ran out of decisions next to the boxes. Now each refusal is a counted veto, and a spot the layer
    allows within the source's 2.5 m stopping distance counts as arrival.
    """
    spec = EpisodeSpec(
        scenario="factory",
        task_id="T8",
        start_pose=4,
        options=drive_options(max_iterations=30, localize=False),
        backend="policy:keyword",
        out_dir=tmp_path / "t8",
        plots=False,
    )
    summary = run_episode(spec)
    record = read_run(tmp_path / "t8")
    refused = [a for a in record.of_type("action") if a.get("vetoed")]
    assert refused, "the layer refused no leg: the episode no longer exercises the fix"
    assert summary["safety_vetoes"] >= len(refused)
    assert summary["success"] and summary["iterations"] < 30, summary
