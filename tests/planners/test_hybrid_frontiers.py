"""Frontier values of the hybrid planner: described, scored by every answerer, logged, replayed strictly."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest

from llmnav.backends.policy import PolicyBackend
from llmnav.core.chat import ScoreRequest, ScoreResult
from llmnav.core.geometry import Pose2D
from llmnav.planners.base import GroundTruth, drive_options
from llmnav.planners.hybrid.memory import Memory
from llmnav.planners.hybrid.menu import landmarks_near
from llmnav.planners.hybrid.oracle import HybridAnswerKey
from llmnav.planners.hybrid.scoring import (
    FRONTIER_PROMPT,
    ROOM_PROMPT,
    UNDESCRIBED,
    Candidate,
    ScoredChooser,
    frontier_value,
)
from llmnav.runs.runlog import read_run
from llmnav.runs.runner import EpisodeSpec, run_episode
from llmnav.world.scenario import load_scenario

TASK = "Find the pillow"


class BackendContext:
    """What `ScoredChooser` reads of an episode context, answered by a real backend (a policy here)."""

    def __init__(self, backend: Any) -> None:
        self.backend = backend
        self.requests: list[ScoreRequest] = []

    def score(self, request: ScoreRequest, step: int | None) -> ScoreResult:
        self.requests.append(request)
        result: ScoreResult = self.backend.score(request)
        return result


def _menu() -> list[Candidate]:
    """Two frontiers: a long one near the kitchen, a short one beside the bed and wardrobe; nothing else known."""
    return [
        Candidate(1, "frontier", ("stove", "fridge"), 2.0, utility=3.0, place=(2.0, 0.0)),
        Candidate(2, "frontier", ("bed", "wardrobe"), 6.0, utility=1.0, place=(-6.0, 0.0)),
        Candidate(3, "frontier", (), 4.0, utility=2.0, place=(0.0, 4.0)),
        Candidate(4, "complete"),
    ]


def _choose(backend: Any, explore: str) -> tuple[Any, BackendContext]:
    ctx = BackendContext(backend)
    chooser = ScoredChooser(ctx, TASK, mapped=False, explore=explore)  # type: ignore[arg-type]
    chooser.intent = "go"
    return chooser.choose(_menu(), turned=True, step=3), ctx


def test_the_value_is_the_utility_times_the_likelihood_ratio() -> None:
    assert frontier_value(2.0, 0.0) == pytest.approx(math.log(2.0))
    # one nat of relevance is worth a factor e of utility
    assert frontier_value(1.0, 1.0) == pytest.approx(frontier_value(math.e, 0.0))


def test_nearest_and_utility_ignore_the_descriptions() -> None:
    nearest, ctx = _choose(PolicyBackend("keyword"), "nearest")
    assert nearest.number == 1 and not any(r.prefix.startswith(FRONTIER_PROMPT[:40]) for r in ctx.requests)
    useful, _ = _choose(PolicyBackend("keyword"), "utility")
    assert useful.number == 1


def test_keyword_scores_the_frontier_whose_landmarks_share_the_tasks_words() -> None:
    """`policy:keyword` counts shared words: "Find the bed" favours the frontier beside the bed, 1 nat up."""
    ctx = BackendContext(PolicyBackend("keyword"))
    chooser = ScoredChooser(ctx, "Find the bed", mapped=False, explore="scored")  # type: ignore[arg-type]
    chooser.intent = "go"
    decision = chooser.choose(_menu(), turned=True, step=3)
    rows = {row["option"]: row for row in decision.frontiers}
    assert rows[2]["pmi"] == pytest.approx(1.0) and rows[1]["pmi"] == pytest.approx(0.0)
    assert rows[3]["description"] == UNDESCRIBED
    # 1 nat beats a utility three times as large only when e * 1.0 > 3.0: it does not (2.72)
    assert decision.number == 1
    assert rows[2]["value"] == pytest.approx(math.log(1.0) + 1.0)
    asked = [r for r in ctx.requests if r.prefix.startswith("A mobile robot") and "explores toward" in r.prefix]
    assert len(asked) == 2 and asked[0].places == ((2.0, 0.0), (-6.0, 0.0), (0.0, 4.0))


def test_first_scores_by_position_and_random_by_a_seeded_draw() -> None:
    first, _ = _choose(PolicyBackend("first"), "scored")
    pmi = [row["pmi"] for row in first.frontiers]
    # the task term and the content-free term are both by position: no frontier is favoured
    assert pmi == [0.0, 0.0, 0.0] and first.number == 1
    one, _ = _choose(PolicyBackend("random:3"), "scored")
    again, _ = _choose(PolicyBackend("random:3"), "scored")
    other, _ = _choose(PolicyBackend("random:4"), "scored")
    assert one.frontiers == again.frontiers and one.frontiers != other.frontiers


def test_a_room_is_named_only_when_the_landmarks_make_it_likelier() -> None:
    # log-probability of a room word after "the room with <landmark> is the"; the content-free term is -5
    scored: dict[tuple[str, str], float] = {}
    asked: list[str] = []

    class Rooms:
        def score(self, request: ScoreRequest, step: int | None) -> ScoreResult:
            from llmnav.core.chat import ContinuationScore

            thing = request.prefix.removeprefix("In a building, the room with ").removesuffix(" is the")
            asked.append(thing)
            values = [scored.get((thing, c.strip()), -5.0) for c in request.continuations]
            return ScoreResult(tuple(ContinuationScore(v, 1) for v in values), 0.0, "fake")

    def fresh() -> ScoredChooser:
        asked.clear()
        return ScoredChooser(Rooms(), TASK, mapped=False, explore="scored")  # type: ignore[arg-type]

    chooser = fresh()
    assert chooser.describe(("bed", "wardrobe")) == "the bed and the wardrobe"  # no room above min_pmi
    assert sorted(set(asked)) == ["N/A", "the bed", "the wardrobe"]  # one question per landmark, not per set
    scored[("the bed", "bedroom")] = -4.4  # 0.6 nats above the content-free term: not enough alone
    scored[("the wardrobe", "bedroom")] = -4.3  # 0.7 nats
    chooser = fresh()
    assert chooser.describe(("bed",)) == "the bed"
    # together 1.3 nats >= min_pmi (1.0): the landmarks' PMIs add up
    assert chooser.describe(("bed", "wardrobe")) == "the bedroom"  # the room stands for its landmarks
    before = len(asked)
    assert chooser.describe(("wardrobe", "bed")) == "the bedroom"
    assert len(asked) == before  # a new set of known landmarks asks nothing
    scored[("the stove", "kitchen")] = -1.0  # 4 nats
    scored[("the stove", "bedroom")] = -8.0  # -3 nats: beside a stove, a bedroom is unlikely
    assert chooser.describe(("bed", "wardrobe", "stove")) == "the kitchen"
    assert chooser.describe(("wardrobe", "stove")) == "the kitchen"  # kitchen 0 + 4 nats, bedroom 0.7 - 3
    assert chooser.describe(()) == UNDESCRIBED
    assert ROOM_PROMPT.format(task="the bed") == "In a building, the room with the bed is the"


def test_landmarks_near_a_frontier_nearest_first_each_name_once() -> None:
    memory = Memory(
        landmarks={"b": (1.0, 0.0), "w": (2.0, 0.0), "b2": (0.5, 0.0), "far": (9.0, 0.0)},
        labels={"b": "bed", "w": "wardrobe", "b2": "bed", "far": "stove"},
    )
    assert landmarks_near(memory, (0.0, 0.0), 3.0, 3) == ("bed", "wardrobe")
    assert landmarks_near(memory, (0.0, 0.0), 3.0, 1) == ("bed",)


def test_oracle_answers_score_the_frontier_nearest_the_target_by_path() -> None:
    scenario = load_scenario("factory")
    task = scenario.task("T9")  # the fire extinguisher at about (9.65, -7)
    key = HybridAnswerKey(GroundTruth(scenario, task, lambda: Pose2D(0.0, 0.0, 0.0), lambda: 0.0))
    places = ((-8.0, 6.0), (8.0, -5.0), (0.0, 0.0))
    texts = (" the oil barrel", " unexplored space", " the oil barrel")
    assert key.scores(ScoreRequest(FRONTIER_PROMPT.format(task=task.text), texts, places)) == (-10.0, 0.0, -10.0)
    assert key.scores(ScoreRequest(FRONTIER_PROMPT.format(task="N/A"), texts, places)) == (-10.0,) * 3
    # The words do not matter to the oracle, only where the frontier lies.
    moved = ((8.0, -5.0), (-8.0, 6.0), (0.0, 0.0))
    assert key.scores(ScoreRequest(FRONTIER_PROMPT.format(task=task.text), texts, moved)) == (0.0, -10.0, -10.0)


# --- end to end ---------------------------------------------------------------------------------
def _drive(tmp_path: Path, name: str, backend: str, **options: Any) -> dict[str, Any]:
    from llmnav.buildings.suite import suite_files

    flat = suite_files("generated:flat:1", tmp_path / "scenarios")[0]  # flat 0: T1's targets out of sight
    spec = EpisodeSpec(
        scenario=str(flat),
        task_id="T1",
        options=drive_options(**({"planner": "hybrid", "max_iterations": 5, "explore": "scored"} | options)),
        backend=backend,
        out_dir=tmp_path / name,
        plots=False,
    )
    return run_episode(spec)


def test_frontier_scores_are_logged_and_a_strict_replay_repeats_them(tmp_path: Path) -> None:
    live = _drive(tmp_path, "live", "policy:oracle")
    record = read_run(tmp_path / "live")
    assert [e["explore"] for e in record.of_type("planner")] == ["scored"]
    assert live["condition"]["explore"] == "scored"
    scored = [d for d in record.of_type("decision") if any("pmi" in row for row in d.get("frontiers", []))]
    assert scored, "no decision explored by scores"
    for decision in scored:
        rows = decision["frontiers"]
        assert all({"description", "utility", "pmi", "value"} <= set(row) for row in rows)
        assert decision["option"] == max(rows, key=lambda r: r["value"])["option"]
        assert sorted(r["pmi"] for r in rows)[-1] == 10.0  # oracle answers: one frontier leads toward the target
    again = _drive(tmp_path, "again", f"replay:{tmp_path / 'live'}")
    assert again["final_pose"] == live["final_pose"]

    def decisions(run: Path) -> list[dict[str, Any]]:
        return [{k: v for k, v in e.items() if k != "t_wall"} for e in read_run(run).of_type("decision")]

    assert decisions(tmp_path / "again") == decisions(tmp_path / "live")


def test_the_viewer_draws_each_decisions_frontier_values_on_the_map(tmp_path: Path) -> None:
    import re

    from llmnav.view.api import write_view

    _drive(tmp_path, "live", "policy:oracle")
    rows = [row for d in read_run(tmp_path / "live").of_type("decision") for row in d.get("frontiers", [])]
    page = write_view(tmp_path / "live").page.read_text(encoding="utf-8")
    marks = re.findall(
        r'<g class="frontier( chosen)?"><circle[^>]*><title>([^<]*)</title></circle><text[^>]*>([^<]*)</text>', page
    )
    assert len(marks) == len([r for r in rows if "at" in r]) > 0
    scored = [r for r in rows if "value" in r]
    labels = {label for _, _, label in marks}
    assert scored and all(f"{r['value']:+.1f}" in labels for r in scored)
    assert any(chosen for chosen, _, _ in marks)


def test_a_backend_that_cannot_score_explores_by_utility_and_says_so(tmp_path: Path) -> None:
    import json

    from llmnav.backends.replay import write_script

    script = write_script(tmp_path / "script", [json.dumps({"option": 1, "reasoning": "x"})] * 3, purpose="choice")
    summary = _drive(tmp_path, "generated", f"replay:{script}", max_iterations=2)
    assert summary["condition"]["explore"] == "utility (cannot score)"
    assert [e["explore"] for e in read_run(tmp_path / "generated").of_type("planner")] == ["utility (cannot score)"]


# --- relational places ----------------------------------------------------------------------------
def test_a_relation_counts_only_where_it_is_more_relevant_than_its_landmarks() -> None:
    boxes = "spot between the boxes and the fire"
    menu = [
        Candidate(1, "landmark", ("boxes",), 6.0),
        Candidate(2, "landmark", (boxes, "boxes", "fire"), 2.0, place=(1.0, 1.0)),
        Candidate(3, "complete"),
    ]
    # keyword-like scores: the spot shares the boxes' words and no more, so the boxes themselves are taken
    ctx = BackendContext(PolicyBackend("keyword"))
    chooser = ScoredChooser(ctx, "Go to the boxes", mapped=True)  # type: ignore[arg-type]
    chooser.intent = "go"
    assert chooser.choose(menu, turned=True, step=1).number == 1
    # a task that asks for the relation: the spot scores above both landmarks and wins
    asks = ScoredChooser(BackendContext(PolicyBackend("keyword")), "Go between the boxes and the fire", mapped=True)  # type: ignore[arg-type]
    asks.intent = "go"
    decision = asks.choose(menu, turned=True, step=1)
    assert decision.number == 2 and decision.scores[f"{boxes} (1.0, 1.0)"] == pytest.approx(3.0)


def test_relational_places_are_offered_only_to_a_task_that_asks_for_a_relation() -> None:
    from llmnav.planners.hybrid.menu import asks_for_relation

    for task in ("Go between the stairs and the oil barrels", "Wait next to the door", "Stop BY the window",
                 "Park beside the red box", "Go halfway to the exit", "Find a chair near the desk"):  # fmt: skip
        assert asks_for_relation(task), task
    for task in ("Go to the coffee table", "Find somewhere I can lie down", "Go to the nearest exit",
                 "Go to the bypass valve", "Look around the room you are in"):  # fmt: skip
        assert not asks_for_relation(task), task


def test_a_flat_task_gets_no_relational_place_on_its_menus(tmp_path: Path) -> None:
    """Flat 0's T1 names a thing, no relation: its scored menus hold landmarks, frontiers, no "spot"."""
    _drive(tmp_path, "live", "policy:oracle")
    scored = [d for d in read_run(tmp_path / "live").of_type("decision") if d.get("pmi")]
    assert scored and not any(name.startswith("spot ") for d in scored for name in d["pmi"])


def test_oracle_answers_choose_the_place_between_the_stairs_and_the_oil_barrels(tmp_path: Path) -> None:
    """Factory T4 names no landmark ("Go between the stairs and the oil barrels"): a relational place."""
    summary = run_episode(
        EpisodeSpec(
            scenario="factory",
            task_id="T4",
            start_pose=1,
            options=drive_options(planner="hybrid"),
            backend="policy:oracle",
            out_dir=tmp_path / "t4",
            plots=False,
        )
    )
    assert summary["success"] and summary["outcome"] == "completed", summary
    decisions = read_run(tmp_path / "t4").of_type("decision")
    went = [d["rule"] for d in decisions if d["rule"].startswith("go to")]
    assert went and went[-1].startswith("go to spot between the") and "stairs" in went[-1], went
    assert decisions[-1]["rule"].startswith("at spot between the")
