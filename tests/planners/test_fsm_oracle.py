"""The FSM's oracle answers (`policy:oracle`): inside the FSM's guard and box, aimed at e_pos's stop point,
an episode on `maze_arena` that stops there, and its strict replay."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest

from llmnav.backends.policy import PolicyBackend
from llmnav.backends.replay import ReplayBackend
from llmnav.core.geometry import Pose2D
from llmnav.planners.base import GroundTruth, drive_options
from llmnav.planners.fsm import FsmConfig, FsmPlanner, check_suggestion, state_message
from llmnav.planners.fsm.assist import answer_schema, suggestion_request, system_prompt
from llmnav.planners.fsm.oracle import FsmAnswerKey, sign_stop_point
from llmnav.runs.runlog import RunRecord, read_run
from llmnav.runs.runner import EpisodeSpec, run_episode
from llmnav.world.scenario import load_scenario

CFG = FsmConfig()
MAZE = load_scenario("maze_arena")
STOP = MAZE.object("STOP")  # board at (4.45, 4.96) on the north wall: its stop point is 0.45 m south
OPTIONS = drive_options(planner="fsm", assist="llm")


def key_at(pose: Pose2D) -> FsmAnswerKey:
    task = MAZE.tasks[0]
    key = FsmPlanner(CFG).oracle_answers(GroundTruth(MAZE, task, lambda: pose, lambda: 0.0), OPTIONS)
    assert isinstance(key, FsmAnswerKey)
    return key


def ask(key: FsmAnswerKey, sign: str, distance: float) -> str:
    """The key's reply to the request the FSM publishes for `sign` seen at `distance`."""
    text = state_message(sign, distance, 0.0, 0.03, 0.0)  # what the FSM publishes in APPROACH
    request = suggestion_request(system_prompt(CFG), answer_schema(CFG), text, OPTIONS)
    assert request.messages[-1].text == text
    return key.answer(request)


POSES = [
    Pose2D(4.45, 3.4, math.pi / 2),  # far below the stop sign, on its normal
    Pose2D(4.3, 4.2, math.pi / 2 + 0.3),  # off the normal, heading away from it
    Pose2D(4.45, 4.51, math.pi / 2),  # at the stop point
    Pose2D(4.6, 4.7, 0.0),  # past it, facing the east wall
]


@pytest.mark.parametrize("pose", POSES)
def test_the_oracle_answer_passes_the_fsm_guard_and_its_box(pose):
    key = key_at(pose)
    text = ask(key, "stop", pose.distance_to(*STOP.goal_point))
    verdict, value, detail = check_suggestion(text, 0.0, 0.0, 0.5, CFG)
    assert verdict == "accepted", detail
    assert value is not None
    items = FsmPlanner(CFG).answer_schema()["prefixItems"]
    for number, item in zip(text.strip("[]").split(","), items, strict=True):
        assert item["minimum"] <= int(number) <= item["maximum"]


def test_the_oracle_drives_onto_the_signs_normal_and_brakes_to_zero_at_d_goal():
    stop = sign_stop_point(MAZE, STOP, CFG.d_goal)
    assert stop == pytest.approx((4.45, 4.96 - CFG.d_goal))
    far, off, at, _ = (key_at(p).velocity(f"stop {p.distance_to(*STOP.goal_point):.2f} +0.00 30 0") for p in POSES)
    assert far == (round(CFG.v_max * 1000), 0)  # on the normal, facing the board: full speed, straight
    assert off[1] < 0  # left of the normal and turned further left: turn right, back onto it
    assert at[0] == 0  # braked to zero at d_goal on the true distance
    # The reported distance picks the board among the scenario's boards of the class: SR1 from the start.
    start = key_at(Pose2D(0.6, 0.5, math.pi / 2))
    assert start.velocity("right 1.50 +0.00 30 0") == (round(CFG.v_max * 1000), 0)


def run_oracle(tmp_path: Path, name: str, backend: Any, **options: Any) -> tuple[dict[str, Any], RunRecord]:
    spec = EpisodeSpec(
        scenario="maze_arena",
        task_id="M1",
        start_pose=1,
        options=drive_options(planner="fsm", assist="llm", **options),  # type: ignore[arg-type]
        backend=backend.spec,
        out_dir=tmp_path / name,
    )
    summary = run_episode(spec, backend_obj=backend)
    return summary, read_run(tmp_path / name)


@pytest.fixture(scope="module")
def oracle_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Any], RunRecord]:
    tmp = tmp_path_factory.mktemp("fsm_oracle")
    summary, record = run_oracle(tmp, "oracle", PolicyBackend("oracle"))
    return tmp, summary, record


def test_an_oracle_episode_on_maze_arena_stops_at_the_stop_point(oracle_run):
    _, summary, _ = oracle_run
    metrics = summary["planner_metrics"]
    assert summary["outcome"] == "completed", summary["reason"]
    assert summary["success"] is True
    assert summary["information"] == "oracle"
    assert metrics["accepted"] == metrics["suggestions"] > 100  # every answer through the guard and the box
    assert metrics["e_pos_m"] < 0.1  # FSM-only, same episode: 0.12 m (it stops where its line of sight met
    # the d_goal circle, on a noisy distance)


def test_a_strict_replay_of_an_oracle_run_ends_at_the_same_pose(oracle_run):
    tmp, summary, record = oracle_run
    replay = ReplayBackend(str(tmp / "oracle"))  # strict: every request must match the original's
    again, replayed = run_oracle(tmp, "replayed", replay, model_latency="recorded")
    assert again["outcome"] == summary["outcome"]
    assert replayed.poses() == record.poses()
    assert replayed.poses()[-1] == record.poses()[-1]
