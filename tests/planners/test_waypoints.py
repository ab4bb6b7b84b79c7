"""The waypoint planner (source B) end to end on the simulator with scripted answers: validation that names
every bad point, regeneration up to its bound, P-control execution, obstacle stops with bounded replanning
and a cooldown, target sequences, and grounding a command by the model's choice."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import pytest

from llmnav.backends.replay import ReplayBackend, write_script
from llmnav.guard.parse import correction_message, parse_answer
from llmnav.guard.schemas import response_schema
from llmnav.planners.base import drive_options
from llmnav.planners.prompting import render
from llmnav.planners.waypoints.planner.answers import WaypointList, target_choice_model
from llmnav.runs.runlog import RunRecord, read_run
from llmnav.runs.runner import EpisodeSpec, exit_code, run_episode
from llmnav.world.tasks import SEQUENCE_JOIN

ROOM_105 = (6.5, 1.1)  # [m] goal point of room 105 in corridor_a
BOX = 0.5  # [m] side of a box dropped with --obstacle
BURGER_RADIUS = 0.105  # [m]


def brief(legs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Each leg record's target, whether it was reached and its replans."""
    return [{k: leg[k] for k in ("target", "reached", "replans")} for leg in legs]


def plan_text(*points: tuple[float, float]) -> str:
    """A waypoint answer as the model would write it."""
    return json.dumps([{"x": x, "y": y} for x, y in points])


def script(path: Path, replies: list[str]) -> str:
    """Scripted replies the replay backend returns in order, whatever the prompt."""
    return write_script(path, replies, purpose="waypoints", latency_s=0.25)


def drive(
    tmp_path: Path,
    replies: list[str],
    *,
    tasks: tuple[str, ...] = ("Go to room 105",),
    scenario: str = "corridor_a",
    name: str = "run",
    **options: Any,
) -> tuple[dict[str, Any], RunRecord]:
    replay = ReplayBackend(script(tmp_path / f"{name}-script", replies))
    spec = EpisodeSpec(
        scenario=scenario,
        task_text=SEQUENCE_JOIN.join(tasks),
        options=drive_options(planner="waypoints", **options),
        backend=replay.spec,
        out_dir=tmp_path / name,
    )
    summary = run_episode(spec, backend_obj=replay)
    return summary, read_run(tmp_path / name)


def planner_events(record: RunRecord, kind: str) -> list[dict[str, Any]]:
    return [e for e in record.of_type("planner") if e.get("kind") == kind]


def requests(record: RunRecord) -> list[list[dict[str, Any]]]:
    return [c["request"]["messages"] for c in record.of_type("llm_call")]


def box_distance(x: float, y: float, centre: tuple[float, float]) -> float:
    """Distance from a point to the footprint of a dropped box [m]."""
    dx = max(abs(x - centre[0]) - BOX / 2, 0.0)
    dy = max(abs(y - centre[1]) - BOX / 2, 0.0)
    return math.hypot(dx, dy)


def test_invalid_plan_named_point_by_point_then_valid_plan_executed(tmp_path: Path) -> None:
    bad = plan_text((3.0, 1.7), (3.2, 1.4), (6.5, 0.5))  # outside the margin, too close, off target
    good = plan_text((3.0, 0.5), ROOM_105)
    summary, record = drive(tmp_path, [bad, good, good])
    assert summary["outcome"] == "completed" and exit_code(summary) == 0, summary["reason"]

    # "room 105" names one object: grounding needs no model call
    calls = record.of_type("llm_call")
    assert [c["purpose"] for c in calls] == ["waypoints", "correction"]
    # one guard event per reply, attempts counted from 1, the map rules judged as bounds
    guards = [(g["attempt"], g["outcome"]) for g in record.of_type("guard")]
    assert guards == [(1, "bounds"), (2, "ok")]
    assert [g["target"] for g in planner_events(record, "grounding")] == ["R105"]

    first = calls[0]["request"]
    system = first["messages"][0]["text"]
    assert "- main: x from -1.0 to 14.0, y from -2.0 to 2.0" in system
    assert "Robot: x = 0.00, y = 0.00, heading 0 degrees" in system
    assert 'Target "room 105": x = 6.50, y = 1.10.' in system
    assert "at least 0.5 m from its edges" in system and "at most 3 waypoints" in system
    assert "Obstacles reported on the way so far: none" in system
    assert first["json_schema"]["type"] == "array" and first["json_schema"]["maxItems"] == 3

    attempts = planner_events(record, "waypoint_attempt")
    assert [(a["attempt"], a["valid"]) for a in attempts] == [(1, False), (2, True)]
    problems = attempts[0]["problems"]
    assert problems == [
        "waypoint 1 (3.00, 1.70) is outside every corridor with the 0.5 m margin",
        "waypoint 2 (3.20, 1.40) is 0.36 m from the previous point; keep at least 0.7 m",
        "the final waypoint is 0.60 m from the target (6.50, 1.10); it must be within 0.05 m",
    ]
    # the regeneration turn: the model's own answer, then the feedback naming every problem
    retry = calls[1]["request"]["messages"]
    assert retry[:2] == first["messages"]
    assert retry[2] == {"role": "assistant", "text": bad}
    assert retry[3]["text"] == render("waypoints_feedback", problems="\n".join(f"- {p}" for p in problems))
    assert [(g["attempt"], g["outcome"]) for g in record.of_type("guard")] == [(1, "bounds"), (2, "ok")]

    actions = record.of_type("action")
    assert [(a["command"], a["parameters"], a["stopped_reason"]) for a in actions] == [
        ("WAYPOINT", [3.0, 0.5], None),
        ("WAYPOINT", [6.5, 1.1], None),
    ]
    for action in actions:  # each waypoint reached within the 0.1 m tolerance
        assert math.dist(action["pose_after"][:2], action["parameters"]) <= 0.1 + 0.01
    assert summary["distance_m"] <= 0.11 and summary["success"]

    # the P-controller's limits, seen in the trajectory: 0.4 m/s cruising, turns at most 2 rad/s
    poses = [e for e in record.of_type("pose") if "t_sim" in e]
    assert len(poses) > 20 and poses[-1]["t_sim"] > 15.0  # pose events carry sim time
    speeds, turn_rates = [], []
    for a, b in zip(poses, poses[1:], strict=False):
        dt = b["t_sim"] - a["t_sim"]
        if dt > 0.05:
            speeds.append(math.dist(a["pose"][:2], b["pose"][:2]) / dt)
            turn = math.remainder(b["pose"][2] - a["pose"][2], math.tau)
            turn_rates.append(abs(turn) / dt)
    assert 0.37 <= max(speeds) <= 0.41 and max(turn_rates) <= 2.0 + 1e-6

    metrics = summary["planner_metrics"]
    assert (metrics["generations"], metrics["valid_generations"], metrics["wgsr"]) == (2, 1, 50.0)
    # planning time = the model's latency (two scripted replies of 0.25 s) plus our own work
    assert 0.5 <= metrics["planning_time_s"] < 0.8
    path = math.dist((0, 0), (3.0, 0.5)) + math.dist((3.0, 0.5), ROOM_105)  # [m] the plan's length
    assert path - 0.25 < summary["path_length_m"] < path + 0.1
    assert summary["path_length_m"] / 0.4 <= metrics["execution_time_s"] <= summary["sim_time_s"] + 1e-6
    assert (metrics["collision_events"], metrics["replans"], metrics["replanning_rate"]) == (0, 0, 0.0)
    assert brief(metrics["legs"]) == [{"target": "R105", "reached": True, "replans": 0}]
    (leg,) = metrics["legs"]  # the whole command is one leg: its numbers are the episode's
    assert (leg["generations"], leg["valid_generations"], leg["wgsr"], leg["plan_failed"]) == (2, 1, 50.0, False)
    assert leg["planning_time_s"] == pytest.approx(metrics["planning_time_s"])
    assert leg["execution_time_s"] == pytest.approx(metrics["execution_time_s"], abs=1e-3)
    assert leg["path_length_m"] == pytest.approx(summary["path_length_m"], abs=0.02)
    assert leg["start"] == [0.0, 0.0, 0.0] and math.dist(leg["end"][:2], ROOM_105) <= 0.11
    assert summary["json_errors"] == 1 and summary["collisions"] == 0


def test_regeneration_stops_at_max_generations_with_the_reason(tmp_path: Path) -> None:
    prose = "Sure! Drive east along the corridor."
    wrong_shape = '[{"x": 2.0}]'
    too_many = plan_text((1.0, 0.0), (2.0, 0.0), (3.0, 0.0), ROOM_105)
    summary, record = drive(tmp_path, [prose, wrong_shape, too_many, plan_text(ROOM_105)], max_generations=3)
    assert summary["outcome"] == "failed" and exit_code(summary) == 1
    assert summary["reason"] == "no valid waypoints for room 105 after 3 generations"
    assert len(record.of_type("llm_call")) == 3  # the fourth scripted answer is never asked for
    assert [g["outcome"] for g in record.of_type("guard")] == ["parse", "schema", "bounds"]
    attempts = planner_events(record, "waypoint_attempt")
    assert attempts[0]["problems"][0].startswith("parse: ") and attempts[1]["problems"][0].startswith("schema: ")
    assert "4 waypoints; at most 3 are allowed here" in attempts[2]["problems"]
    # a parse or schema failure gets the guard's correction with the expected schema
    msgs = requests(record)
    schema = record.of_type("llm_call")[0]["request"]["json_schema"]
    for k, text in enumerate((prose, wrong_shape)):
        assert msgs[k + 1][-1]["text"] == correction_message(parse_answer(text, WaypointList), schema)
    assert record.of_type("action") == []
    metrics = summary["planner_metrics"]
    assert (metrics["generations"], metrics["valid_generations"], metrics["wgsr"]) == (3, 0, 0.0)
    assert brief(metrics["legs"]) == [{"target": "R105", "reached": False, "replans": 0}]
    assert metrics["plan_failed"] and metrics["legs"][0]["plan_failed"] and metrics["legs"][0]["path_length_m"] == 0


def test_a_segment_through_an_unexpected_obstacle_is_vetoed_then_replanned(tmp_path: Path) -> None:
    box = (3.5, 0.0)
    straight = plan_text((5.0, 0.0), ROOM_105)  # valid on the map, but the box stands on it
    detour = plan_text((2.6, 1.2), (4.5, 1.2), ROOM_105)
    summary, record = drive(tmp_path, [straight, straight, detour], obstacles=(box,))
    assert summary["outcome"] == "completed", summary["reason"]

    # the motion layer refused the segment through the box before the robot moved, and the log says so
    first = record.of_type("action")[0]
    assert (first["index"], first["stopped_reason"]) == (1, "vetoed")
    assert first["pose_after"] == first["pose_before"]
    assert "would collide with an obstacle" in first["veto"]
    veto = next(g for g in record.of_type("guard") if g["outcome"] == "veto")
    assert veto["motion"] == "GO_TO" and veto["parameters"] == [5.0, 0.0] and veto["error"] == first["veto"]
    assert summary["safety_vetoes"] == 1

    (replan,) = planner_events(record, "replan")
    assert (replan["reason"], replan["number"], replan["waited_s"]) == ("vetoed", 1, 0.0)
    assert replan["pose"] == pytest.approx(first["pose_after"], abs=1e-3)
    assert math.dist(replan["obstacle"], box) < 0.3  # the estimated centre of what was seen

    # the new plan starts from where the robot stands and knows the obstacle
    msgs = requests(record)
    system = msgs[1][0]["text"]
    x, y = replan["pose"][:2]
    assert f"Robot: x = {x:.2f}, y = {y:.2f}" in system
    ox, oy = replan["obstacle"]
    assert f"Obstacles reported on the way so far: ({ox:.2f}, {oy:.2f}) (keep every segment" in system
    attempts = planner_events(record, "waypoint_attempt")
    assert [a["valid"] for a in attempts] == [True, False, True]
    assert attempts[1]["problems"] == [
        f"the segment to waypoint 1 (5.00, 0.00) crosses an obstacle near ({ox:.2f}, {oy:.2f}) seen on the way"
    ]
    assert attempts[1]["problems"][0] in msgs[2][-1]["text"]

    # the detour was driven without touching the box, to the target
    poses = [e["pose"] for e in record.of_type("pose")]
    assert min(box_distance(p[0], p[1], box) for p in poses) > BURGER_RADIUS + 0.1
    assert summary["distance_m"] <= 0.11 and summary["collisions"] == 0
    metrics = summary["planner_metrics"]
    assert (metrics["collision_events"], metrics["vetoed_segments"], metrics["replans"]) == (0, 1, 1)
    assert metrics["replanning_rate"] == pytest.approx(1 / metrics["execution_time_s"])
    assert (metrics["generations"], metrics["valid_generations"]) == (3, 2)


def test_emergency_stop_for_an_obstacle_beside_the_route(tmp_path: Path) -> None:
    # the box's corner passes 0.25 m beside the robot: never within 0.5 m in the ±15° window ahead, but
    # closer than 0.35 m in the half plane ahead -> emergency stop, then a replan away from it
    box = (3.0, 0.5)
    summary, record = drive(
        tmp_path, [plan_text((5.0, 0.0), ROOM_105), plan_text((3.0, -0.8), ROOM_105)], obstacles=(box,)
    )
    assert summary["outcome"] == "completed", summary["reason"]
    first = record.of_type("action")[0]
    assert first["stopped_reason"] == "emergency"
    assert box_distance(*first["pose_after"][:2], box) < 0.35 + 0.02
    (replan,) = planner_events(record, "replan")
    assert replan["reason"] == "emergency" and math.dist(replan["obstacle"], box) < 0.1
    poses = [e["pose"] for e in record.of_type("pose")]
    assert min(box_distance(p[0], p[1], box) for p in poses) > BURGER_RADIUS + 0.1
    assert (summary["planner_metrics"]["collision_events"], summary["collisions"]) == (1, 0)


def test_replans_are_bounded_and_spaced_by_the_cooldown(tmp_path: Path) -> None:
    # a wall of boxes across the corridor: every route is vetoed at the segment that crosses it
    wall = tuple((3.5, y) for y in (-1.75, -1.25, -0.75, -0.25, 0.25, 0.75, 1.25, 1.75))
    replies = [
        plan_text((5.0, 0.0), ROOM_105),
        plan_text((2.6, 1.2), (4.5, 1.2), ROOM_105),
        plan_text((2.6, -1.2), (4.5, -1.2), ROOM_105),
        plan_text((2.6, 0.6), (4.5, 0.6), ROOM_105),
    ]
    summary, record = drive(tmp_path, replies, obstacles=wall, max_replans=2, replan_cooldown_s=10.0)
    assert summary["outcome"] == "failed" and exit_code(summary) == 1
    assert summary["reason"] == "path to room 105 still blocked (vetoed) after 2 replans"
    assert len(record.of_type("llm_call")) == 3
    assert [a["stopped_reason"] for a in record.of_type("action")] == ["vetoed", None, "vetoed", None, "vetoed"]

    replans = planner_events(record, "replan")
    assert [r["number"] for r in replans] == [1, 2]
    assert replans[0]["waited_s"] == 0.0  # the first replan may come at once
    # the second stop came sooner than the cooldown after the first replan: the robot waited, standing
    assert replans[1]["waited_s"] > 0.5
    assert replans[1]["t_sim"] - replans[0]["t_sim"] >= 10.0 - 1e-3
    assert replans[1]["pose"][:2] == pytest.approx(record.of_type("action")[2]["pose_after"][:2], abs=1e-3)
    # each replan lists every obstacle seen so far
    systems = [m[0]["text"] for m in requests(record)]
    for k, text in enumerate(systems):
        listed = text.split("Obstacles reported on the way so far: ")[1].splitlines()[0]
        assert listed.count("(") - listed.count("(keep") == k

    metrics = summary["planner_metrics"]
    assert (metrics["collision_events"], metrics["vetoed_segments"], metrics["replans"]) == (0, 3, 2)
    assert metrics["replanning_rate"] == pytest.approx(2 / metrics["execution_time_s"])
    assert brief(metrics["legs"]) == [{"target": "R105", "reached": False, "replans": 2}]
    assert summary["collisions"] == 0


def test_a_sequence_of_targets_is_driven_leg_by_leg(tmp_path: Path) -> None:
    to_window = plan_text((6.0, 0.0), (13.1, 0.0))
    back_to_105 = plan_text((9.0, 0.6), ROOM_105)
    summary, record = drive(tmp_path, [to_window, back_to_105], tasks=("Go to the window", "Go to room 105"))
    assert summary["outcome"] == "completed", summary["reason"]
    assert summary["task_id"] == "SEQ"
    assert [(g["step"], g["target"]) for g in planner_events(record, "grounding")] == [(1, "WIN"), (2, "R105")]
    systems = [m[0]["text"] for m in requests(record)]
    assert 'Target "window": x = 13.10, y = 0.00.' in systems[0]
    assert 'Target "room 105": x = 6.50, y = 1.10.' in systems[1]
    actions = record.of_type("action")
    assert [(a["step"], a["parameters"]) for a in actions] == [
        (1, [6.0, 0.0]),
        (1, [13.1, 0.0]),
        (2, [9.0, 0.6]),
        (2, [6.5, 1.1]),
    ]
    at_window = actions[1]["pose_after"]
    assert math.dist(at_window[:2], (13.1, 0.0)) <= 0.11
    # the second leg is planned from where the first one ended
    assert f"Robot: x = {at_window[0]:.2f}, y = {at_window[1]:.2f}" in systems[1]
    assert summary["distance_m"] <= 0.11
    metrics = summary["planner_metrics"]
    assert brief(metrics["legs"]) == [
        {"target": "WIN", "reached": True, "replans": 0},
        {"target": "R105", "reached": True, "replans": 0},
    ]
    first, second = metrics["legs"]
    assert second["start"] == first["end"]  # each leg starts where the last one ended
    assert first["path_length_m"] + second["path_length_m"] == pytest.approx(summary["path_length_m"], abs=0.02)
    assert (metrics["generations"], metrics["wgsr"]) == (2, 100.0)


def test_an_ambiguous_command_is_grounded_by_the_models_choice(tmp_path: Path) -> None:
    # corridor_b has two windows: the model picks one from the list; an unknown id gets a correction
    replies = [
        '{"object_id": "WIN3"}',
        '{"object_id": "WIN2"}',
        plan_text((7.0, 0.0), (7.0, 8.0), (8.0, 15.1)),
    ]
    summary, record = drive(tmp_path, replies, scenario="corridor_b", tasks=("Go to the window",))
    assert summary["outcome"] == "completed", summary["reason"]
    calls = record.of_type("llm_call")
    assert [c["purpose"] for c in calls] == ["ground", "correction", "waypoints"]
    guards = [(g["purpose"], g["attempt"], g["outcome"]) for g in record.of_type("guard")]
    assert guards == [("ground", 1, "schema"), ("ground", 2, "ok"), ("waypoints", 1, "ok")]
    ask = calls[0]["request"]
    schema = response_schema(target_choice_model(("WIN1", "WIN2")))
    assert ask["json_schema"] == schema and ask["json_schema"]["properties"]["object_id"]["enum"] == [
        "WIN1",
        "WIN2",
    ]
    listing = ask["messages"][1]["text"]
    assert 'Command: "Go to the window"' in listing
    assert "- WIN1: window at (6.0, 15.1)" in listing and "- WIN2: window at (8.0, 15.1)" in listing
    assert "R101" not in listing
    correction = calls[1]["request"]["messages"][-1]["text"]
    model = target_choice_model(("WIN1", "WIN2"))
    assert correction == correction_message(parse_answer(replies[0], model), schema) and "WIN3" in correction
    assert [g["target"] for g in planner_events(record, "grounding")] == ["WIN2"]
    system = calls[2]["request"]["messages"][0]["text"]
    assert 'Target "window": x = 8.00, y = 15.10.' in system
    assert "- side: x from 5.0 to 9.0, y from -2.0 to 16.0" in system and "junction at (7.0, 0.0)" in system
    assert math.dist(summary["final_pose"][:2], (8.0, 15.1)) <= 0.11
    assert summary["target_index"] == 1 and summary["success"]
    # grounding time is part of the planning time: three scripted replies of 0.25 s
    assert summary["planner_metrics"]["planning_time_s"] >= 0.75


def test_grounding_gives_up_after_three_unlisted_ids(tmp_path: Path) -> None:
    replies = ['{"object_id": "door"}', '{"object_id": "R101"}', "WIN1 please"]
    summary, record = drive(tmp_path, replies, scenario="corridor_b", tasks=("Go to the window",))
    assert summary["outcome"] == "aborted" and exit_code(summary) == 3  # a model failure
    assert summary["reason"] == "the model named no listed object for 'Go to the window' after 3 tries"
    assert [c["purpose"] for c in record.of_type("llm_call")] == ["ground", "correction", "correction"]
    assert [g["attempt"] for g in record.of_type("guard")] == [1, 2, 3]
    assert record.of_type("action") == []


def test_strict_replay_of_a_replanning_run_reproduces_it(tmp_path: Path) -> None:
    box = (3.5, 0.0)
    replies = [
        plan_text((5.0, 0.0), ROOM_105),
        plan_text((5.0, 0.0), ROOM_105),
        plan_text((2.6, 1.2), (4.5, 1.2), ROOM_105),
    ]
    first, rec1 = drive(tmp_path, replies, obstacles=(box,), name="original")
    # strict: every request (prompts with the replanning pose and obstacle, feedback turns) must match
    replay = ReplayBackend(str(tmp_path / "original"))
    spec = EpisodeSpec(
        scenario="corridor_a",
        task_text="Go to room 105",
        options=drive_options(planner="waypoints", obstacles=(box,)),
        backend=replay.spec,
        out_dir=tmp_path / "again",
    )
    second = run_episode(spec, backend_obj=replay)
    rec2 = read_run(tmp_path / "again")
    assert second["outcome"] == first["outcome"] == "completed"
    assert [e["pose"] for e in rec2.of_type("pose")] == [e["pose"] for e in rec1.of_type("pose")]
    assert [c["request"] for c in rec2.of_type("llm_call")] == [c["request"] for c in rec1.of_type("llm_call")]
    m1, m2 = first["planner_metrics"], second["planner_metrics"]
    for key in ("generations", "valid_generations", "replans", "collision_events", "execution_time_s"):
        assert m1[key] == m2[key], key
    # planning time is the recorded model latency plus our own (small) work
    assert m2["planning_time_s"] == pytest.approx(m1["planning_time_s"], abs=0.1)
