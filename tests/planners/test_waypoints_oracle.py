"""The waypoint planner's oracle answers (`policy:oracle`): every bundled corridor task's plan passes the
planner's own guard at the first attempt, a drive with them reaches the target, and a strict replay of that
drive ends where it ended."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from llmnav.core.chat import ChatRequest, ChatResult, Message, ScoreRequest
from llmnav.core.geometry import Pose2D
from llmnav.guard.schemas import response_schema
from llmnav.mapping.grid import build_grid
from llmnav.planners.base import GroundTruth, drive_options
from llmnav.planners.waypoints.planner import WaypointPlanner, generate_plan
from llmnav.planners.waypoints.planner.answers import target_choice_model
from llmnav.planners.waypoints.planner.oracle import OTHER_LOGPROB, WaypointAnswerKey
from llmnav.runs.runlog import read_run
from llmnav.runs.runner import EpisodeSpec, run_episode
from llmnav.world.scenario import Scenario, Task, load_scenario

# (scenario, task) -> the oracle's plan from the task's first start pose: straight within a corridor,
# through the junction point (7, 0) of corridor_b or (-6.5, -3) / (6.5, -3) of corridor_c otherwise.
PLANS = {
    ("corridor_a", "A1"): [(1.5, 1.1)],
    ("corridor_a", "A2"): [(4.0, -1.1)],
    ("corridor_a", "A3"): [(9.0, 1.1)],
    ("corridor_a", "A4"): [(11.5, -1.1)],
    ("corridor_a", "A5"): [(13.1, 0.0)],
    ("corridor_b", "B1"): [(1.0, 1.1)],
    ("corridor_b", "B2"): [(4.0, -1.1)],
    ("corridor_b", "B3"): [(7.0, 0.0), (5.9, 6.0)],
    ("corridor_b", "B4"): [(7.0, 0.0), (8.1, 11.0)],
    ("corridor_b", "B5"): [(7.0, 0.0), (6.0, 15.1)],
    ("corridor_c", "C1"): [(-6.5, -3.0), (-8.1, 1.5)],
    ("corridor_c", "C2"): [(-6.5, -3.0), (-4.9, 21.3)],
    ("corridor_c", "C3"): [(6.5, -3.0), (4.9, 1.0)],
    ("corridor_c", "C4"): [(6.5, -3.0), (8.1, 21.8)],
    ("corridor_c", "C5"): [(0.0, -4.6)],
    ("corridor_c", "C6"): [(6.5, -3.0), (6.5, 23.1)],
    ("corridor_c", "C7"): [(-6.5, -3.0), (-8.1, 11.4)],
}


def start_of(scenario: Scenario, task: Task) -> Pose2D:
    first = scenario.start_poses(task)[0]
    return Pose2D(first.x, first.y, math.radians(first.yaw_deg))


def key_for(scenario: Scenario, task: Task, pose: Pose2D) -> WaypointAnswerKey:
    return WaypointAnswerKey(GroundTruth(scenario, task, lambda: pose, lambda: 0.0), keep_clear_m=0.35)


def test_every_bundled_corridor_task_is_listed() -> None:
    bundled = {(name, t.id) for name in ("corridor_a", "corridor_b", "corridor_c") for t in load_scenario(name).tasks}
    assert bundled == set(PLANS)


@pytest.mark.parametrize(("scenario_name", "task_id"), sorted(PLANS))
def test_the_oracle_plan_passes_the_planners_guard_first_time(scenario_name: str, task_id: str) -> None:
    scenario = load_scenario(scenario_name)
    task = scenario.task(task_id)
    start = start_of(scenario, task)
    key = key_for(scenario, task, start)

    def call(request: ChatRequest, purpose: str) -> ChatResult:
        return ChatResult(text=key.answer(request), latency_s=0.0, model="oracle")

    target = scenario.object(task.targets[0].object or "")
    plan = generate_plan(scenario, target, start, call, max_generations=3, grid=build_grid(scenario))
    assert [(a.outcome, a.problems) for a in plan.attempts] == [("ok", [])]
    assert plan.waypoints == PLANS[(scenario_name, task_id)]
    assert plan.wgsr == 100.0


def test_grounding_is_answered_with_the_true_target_by_pick_and_by_scores() -> None:
    scenario = load_scenario("corridor_a")
    task = scenario.task("A5")  # "Go to the window"
    key = key_for(scenario, task, start_of(scenario, task))
    model = target_choice_model(("R101", "WIN", "R110"))
    pick = ChatRequest((Message("user", 'Command: "Go to the window"\n\nKnown objects: ...'),), response_schema(model))
    assert json.loads(key.answer(pick)) == {"object_id": "WIN"}
    scored = key.scores(ScoreRequest("Go to the window. The robot drives to the", (" room 101", " window")))
    assert scored == (OTHER_LOGPROB, 0.0)
    assert key.scores(ScoreRequest("N/A. The robot drives to the", (" room 101", " window"))) == (0.0, 0.0)


def test_the_planner_offers_oracle_answers() -> None:
    assert WaypointPlanner.offers_oracle_answers()


def test_an_oracle_drive_through_the_junction_succeeds_and_replays_strictly(tmp_path: Path) -> None:
    spec = EpisodeSpec(
        scenario="corridor_b",
        task_id="B3",
        options=drive_options(planner="waypoints"),
        backend="policy:oracle",
        out_dir=tmp_path / "oracle",
    )
    first = run_episode(spec)
    assert (first["outcome"], first["success"], first["answers"]) == ("completed", True, "oracle")
    metrics = first["planner_metrics"]
    assert (metrics["wgsr"], metrics["replans"], metrics["vetoed_segments"]) == (100.0, 0, 0)
    assert first["distance_m"] <= 0.1 + 1e-6
    driven = [e["parameters"] for e in read_run(tmp_path / "oracle").of_type("action")]
    assert driven == [[7.0, 0.0], [5.9, 6.0]]

    again = run_episode(
        EpisodeSpec(
            scenario="corridor_b",
            task_id="B3",
            options=drive_options(planner="waypoints"),
            backend=f"replay:{tmp_path / 'oracle' / 'run.jsonl'}",
            out_dir=tmp_path / "again",
        )
    )
    assert again["outcome"] == "completed" and again["final_pose"] == first["final_pose"]
    calls = [read_run(tmp_path / name).of_type("llm_call") for name in ("oracle", "again")]
    assert [c["request"] for c in calls[1]] == [c["request"] for c in calls[0]]


def box_gap(x: float, y: float, box: tuple[float, float], half: float = 0.25) -> float:
    """Distance [m] from (x, y) to an axis-aligned square box."""
    return math.hypot(max(abs(x - box[0]) - half, 0.0), max(abs(y - box[1]) - half, 0.0))


@pytest.mark.parametrize("box", [(3.5, 0.0), (3.5, 0.55)])
def test_the_oracle_passes_a_box_beyond_the_emergency_stop(tmp_path: Path, box: tuple[float, float]) -> None:
    # Planned on the map inflated only by radius + 0.10 m, the oracle passed the box 0.22-0.34 m off:
    # the guard accepted it, the controller's emergency stop (below 0.35 m) fired, and every replan
    # from beside the box failed (5 emergency stops, or no valid plan).
    summary = run_episode(
        EpisodeSpec(
            scenario="corridor_a",
            task_text="Go to room 105",
            options=drive_options(planner="waypoints", obstacles=(box,)),
            backend="policy:oracle",
            out_dir=tmp_path / "run",
        )
    )
    assert (summary["outcome"], summary["success"]) == ("completed", True), summary["reason"]
    metrics = summary["planner_metrics"]
    assert (metrics["wgsr"], metrics["replans"], metrics["collision_events"]) == (100.0, 0, 0)
    poses = [e["pose"] for e in read_run(tmp_path / "run").of_type("pose")]
    assert min(box_gap(p[0], p[1], box) for p in poses) > 0.35
