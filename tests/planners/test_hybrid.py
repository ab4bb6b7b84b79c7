"""The hybrid planner (the default, `make demo`) with scripted answers: a corridor task by option number,
a factory task found by scanning and exploring, guard corrections, the safety veto on an obstacle the map
lacks, and exact replay."""

from __future__ import annotations

import json
import math
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from llmnav.backends.base import Backend, ChatRequest, ChatResult
from llmnav.backends.replay import ReplayBackend, write_script
from llmnav.core.resources import resource_dir
from llmnav.guard.parse import correction_message, parse_answer
from llmnav.planners.base import drive_options
from llmnav.planners.hybrid import HybridConfig
from llmnav.planners.hybrid.answers import hybrid_choice_model
from llmnav.runs.runlog import RunRecord, read_run
from llmnav.runs.runner import EpisodeSpec, exit_code, run_episode
from llmnav.world.scenario import load_scenario


def choice(option: int, reasoning: str = "scripted") -> str:
    return json.dumps({"option": option, "reasoning": reasoning})


def script(path: Path, replies: list[str]) -> str:
    """Scripted replies the replay backend returns in order, whatever the prompt."""
    return write_script(path, replies, purpose="choice", latency_s=0.1)


def options_in(user_turn: str) -> dict[int, str]:
    """The numbered options of a decision's user turn (its only numbered lines)."""
    return {int(n): text for n, text in re.findall(r"^(\d+)\. (.+)$", user_turn, re.MULTILINE)}


def menu(request: ChatRequest) -> dict[int, str]:
    """The numbered options of a request's decision turn."""
    return options_in(next(m.text for m in request.messages if m.role == "user"))


class MenuReader(Backend):
    """Answers by reading the menu: `policy(options, decision_index)` returns the option number."""

    name = "menu"

    def __init__(self, policy: Callable[[dict[int, str], int], int]) -> None:
        super().__init__("test")
        self.policy = policy
        self.menus: list[dict[int, str]] = []

    def chat(self, request: ChatRequest) -> ChatResult:
        options = menu(request)
        self.menus.append(options)
        return ChatResult(choice(self.policy(options, len(self.menus) - 1)), 0.01, "menu")


def first(options: dict[int, str], prefix: str) -> int | None:
    return next((n for n, text in options.items() if text.startswith(prefix)), None)


def drive(
    tmp_path: Path,
    backend: Backend,
    *,
    scenario: str = "corridor_a",
    task_id: str | None = None,
    task_text: str | None = None,
    pose: int = 1,
    name: str = "run",
    **options: Any,
) -> tuple[dict[str, Any], RunRecord]:
    options.setdefault("sensing", ("lidar",))
    # These tests exercise the relevance ordering on the true map, as the planner worked before the
    # information modes (test_information.py covers the neutral, sensed defaults).
    options.setdefault("menu_order", "relevance")
    if "factory" in scenario:
        options.setdefault("information", "oracle")
    spec = EpisodeSpec(
        scenario=scenario,
        task_id=task_id,
        task_text=task_text,
        start_pose=pose,
        options=drive_options(planner="hybrid", **options),
        backend=backend.spec,
        out_dir=tmp_path / name,
    )
    summary = run_episode(spec, backend_obj=backend)
    return summary, read_run(tmp_path / name)


def user_turns(record: RunRecord) -> list[str]:
    """The decision prompt (first user turn) of every model call."""
    return [
        next(m["text"] for m in c["request"]["messages"] if m["role"] == "user") for c in record.of_type("llm_call")
    ]


def test_corridor_room_by_option_number_then_finish(tmp_path: Path) -> None:
    replay = ReplayBackend(script(tmp_path / "script", [choice(1), choice(1)]))
    summary, record = drive(tmp_path, replay, task_text="Go to room 101")
    assert summary["outcome"] == "completed" and summary["success"] and exit_code(summary) == 0
    turns = user_turns(record)
    assert "1. Go to room 101, " in turns[0] and "name matches task" in turns[0]
    assert "Explore" not in turns[0]  # the corridor map is published: no frontier options
    # at the room the menu shrinks to what still makes sense: finish, or take another look
    assert options_in(turns[1]) == {
        1: "Finish (at room 101)",
        2: "Turn a full circle to look around",
    }
    scenario = load_scenario("corridor_a")
    plate = scenario.object("R101")
    x, y, yaw = record.poses()[-1]
    assert math.dist((x, y), plate.goal_point) < 0.5 and summary["distance_m"] < 0.5
    facing = math.atan2(plate.center[1] - y, plate.center[0] - x)
    assert abs(math.remainder(facing - yaw, math.tau)) < math.radians(10)
    assert [a["command"] for a in record.of_type("action")] == ["GOTO", "COMPLETE"]
    assert summary["collisions"] == 0 and summary["iterations"] == 2
    # pose events carry sim time (the runner's hook stays in place)
    times = [e["t_sim"] for e in record.of_type("pose")]
    assert times == sorted(times) and times[-1] > 3.0


@pytest.mark.parametrize("multimodal", [True, False])
def test_the_camera_image_is_rendered_only_when_the_model_sees_it(tmp_path: Path, multimodal: bool) -> None:
    from llmnav.view.api import write_view

    replay = ReplayBackend(script(tmp_path / "script", [choice(1), choice(1)]))
    replay.multimodal = multimodal  # the scripted replies stand for a multimodal model unless told
    _summary, record = drive(tmp_path, replay, task_text="Go to room 101", sensing=("lidar", "image"))
    observed = [e["image"] for e in record.of_type("observation")]
    sent = [m.get("images", []) for c in record.of_type("llm_call") for m in c["request"]["messages"]]
    stored = sorted(p.stem for p in (tmp_path / "run" / "images").glob("*.jpg"))
    if multimodal:  # each decision's request carries the frame its observation logged
        assert len(observed) == 2 and all(observed) and [i for i in sent if i] == [[h] for h in observed]
        assert stored == sorted(set(observed))
    else:  # a text-only model: no frame is rendered, logged or stored, and the view shows none
        assert observed == [None, None] and not any(sent) and stored == []
        page = write_view(tmp_path / "run", tmp_path / "run.html").page.read_text(encoding="utf-8")
        assert "data:image/jpeg" not in page and "Camera image sent" not in page


def test_frames_always_keeps_every_frame_for_the_viewer_without_sending_it(tmp_path: Path) -> None:
    from llmnav.view.api import write_view

    replay = ReplayBackend(script(tmp_path / "script", [choice(1), choice(1)]))
    replay.multimodal = False
    _summary, record = drive(
        tmp_path, replay, task_text="Go to room 101", sensing=("lidar", "image"), frames="always"
    )
    observed = [e["image"] for e in record.of_type("observation")]
    sent = [m.get("images", []) for c in record.of_type("llm_call") for m in c["request"]["messages"]]
    stored = sorted(p.stem for p in (tmp_path / "run" / "images").glob("*.jpg"))
    assert len(observed) == 2 and all(observed) and stored == sorted(set(observed))
    assert not any(sent)  # kept for the viewer, still not sent to a text-only model
    page = write_view(tmp_path / "run", tmp_path / "run.html").page.read_text(encoding="utf-8")
    assert "data:image/jpeg" in page


def wanting(target: str, *, scan_first: bool) -> Callable[[dict[int, str], int], int]:
    """A policy: finish at the target, else go to it when listed, else scan (once) or explore."""
    scanned: list[bool] = []

    def policy(options: dict[int, str], index: int) -> int:
        for prefix in ("Finish (at", f"Go to {target}"):
            number = first(options, prefix)
            if number is not None:
                return number
        if scan_first and not scanned:
            scanned.append(True)
            return first(options, "Turn a full circle") or 0
        return first(options, "Explore") or first(options, "Turn a full circle") or 0

    return policy


@pytest.mark.parametrize(("pose", "scan_first"), [(4, True), (3, False)])
def test_factory_target_appears_only_after_scanning_or_exploring(tmp_path: Path, pose: int, scan_first: bool) -> None:
    target = "dark brown wooden boxes"
    reader = MenuReader(wanting(target, scan_first=scan_first))
    summary, record = drive(
        tmp_path,
        reader,
        scenario="factory",
        task_id="T8",
        pose=pose,
        sensing=("lidar", "detections"),
        max_iterations=12,
    )
    assert summary["outcome"] == "completed" and summary["success"], summary["reason"]
    assert summary["distance_m"] <= 2.5 and summary["collisions"] == 0
    listed = [any(t.startswith(f"Go to {target}") for t in m.values()) for m in reader.menus]
    assert not listed[0] and listed[-2]  # hidden at the start, listed once seen
    revealing = reader.menus[listed.index(True) - 1]
    chosen = [json.loads(c["reply"]["text"])["option"] for c in record.of_type("llm_call")]
    kind = revealing[chosen[listed.index(True) - 1]]
    assert kind.startswith("Turn a full circle" if scan_first else "Explore")
    commands = [a["command"] for a in record.of_type("action")]
    assert commands[-1] == "COMPLETE" and commands[-2] == "GOTO"
    assert ("SCAN" in commands) == scan_first
    # with detections sensed, the model's perception text names the boxes once they are in view
    perceived = [turn.split("\n1. ")[0] for turn in user_turns(record)]
    assert "dark brown wooden boxes" not in perceived[0]
    assert any("dark brown wooden boxes" in text for text in perceived[1:])


@pytest.mark.parametrize(
    ("task_id", "commands"),
    [("T8", ["SCAN", "GOTO", "COMPLETE"]), ("T6", ["SCAN", "COMPLETE"])],
)
def test_always_answering_one_still_succeeds(
    tmp_path: Path, task_id: str, commands: list[str], ideal_scenario: Callable[[str], str]
) -> None:
    # A tiny model leans hard toward option 1, so the relevance menu lists the most useful option first:
    # look around while nothing the task names is known, then the named landmark, then Finish once there.
    # Ideal sensing: with odometry drift a leg may end short of the stand point and take a second leg.
    reader = MenuReader(lambda options, index: 1)
    factory = ideal_scenario("factory")
    summary, record = drive(tmp_path, reader, scenario=factory, task_id=task_id, pose=1, max_iterations=6)
    assert summary["outcome"] == "completed" and summary["success"], summary["reason"]
    assert [a["command"] for a in record.of_type("action")] == commands
    assert reader.menus[0][1] == "Turn a full circle to look around"
    assert reader.menus[-1][1].startswith("Finish (")
    # once done, nothing but finishing is offered (a second turn on the same spot would show nothing new)
    assert list(reader.menus[-1].values()) in (
        ["Finish (at dark brown wooden boxes)"],
        ["Finish (at dark brown wooden boxes)", "Turn a full circle to look around"],
        ["Finish (you have looked around)"],
    )


def test_malformed_and_out_of_range_answers_get_corrections(tmp_path: Path) -> None:
    replies = ["I would go to the room", choice(42), choice(1), choice(1)]
    replay = ReplayBackend(script(tmp_path / "script", replies))
    summary, record = drive(tmp_path, replay, task_text="Go to room 101")
    assert summary["outcome"] == "completed" and summary["success"]
    calls = record.of_type("llm_call")
    assert [c["purpose"] for c in calls] == ["choice", "correction", "correction", "choice"]
    guards = [(g["step"], g["attempt"], g["outcome"]) for g in record.of_type("guard")]
    assert guards == [(1, 1, "parse"), (1, 2, "schema"), (1, 3, "ok"), (2, 1, "ok")]  # attempts from 1, as everywhere
    count = len(menu_of(calls[0]))
    model = hybrid_choice_model(tuple(range(1, count + 1)))
    schema = calls[0]["request"]["json_schema"]
    assert list(schema["properties"])[0] == "option" and schema["properties"]["option"]["enum"] == list(
        range(1, count + 1)
    )
    for call, bad in zip(calls[1:3], replies[:2], strict=True):
        messages = call["request"]["messages"]
        assert messages[-2] == {"role": "assistant", "text": bad}
        assert messages[-1]["text"] == correction_message(parse_answer(bad, model), schema)
    assert "42" in calls[2]["request"]["messages"][-1]["text"]
    assert summary["json_errors"] == 2


def menu_of(call: dict[str, Any]) -> dict[int, str]:
    return options_in(next(m["text"] for m in call["request"]["messages"] if m["role"] == "user"))


def test_exhausted_corrections_abort_with_the_reason(tmp_path: Path) -> None:
    replay = ReplayBackend(script(tmp_path / "script", ["no", choice(0), "unused"]))
    summary, record = drive(tmp_path, replay, task_text="Go to room 101", max_corrections=1)
    assert summary["outcome"] == "aborted" and exit_code(summary) == 3  # a model failure
    assert summary["reason"] == "no valid choice after 1 correction turns"
    assert [g["outcome"] for g in record.of_type("guard")] == ["parse", "schema"]
    assert record.of_type("action") == [] and record.poses()[-1] == record.poses()[0]


def test_an_obstacle_the_map_lacks_is_vetoed_then_avoided(tmp_path: Path) -> None:
    # The box at x = 11 m is beyond the 10 m LiDAR range at the start: the plan runs straight into it, the
    # veto stops the robot before the leg that would hit it, and the same option then detours.
    replay = ReplayBackend(script(tmp_path / "script", [choice(1), choice(1), choice(1)]))
    summary, record = drive(tmp_path, replay, task_text="Go to the window", obstacles=((11.0, 0.0),))
    assert [g["outcome"] for g in record.of_type("guard")] == ["ok", "veto", "ok", "ok"]
    veto = record.of_type("guard")[1]
    assert veto["step"] == 1 and "would collide with an obstacle" in veto["error"]
    vetoed = [a for a in record.of_type("action") if a.get("vetoed")]
    assert len(vetoed) == 1 and vetoed[0]["pose_after"][0] < 10.75 - 0.105
    second = user_turns(record)[1]
    assert "Last: safety stop (" in second
    assert veto["error"] in second
    assert summary["outcome"] == "completed" and summary["success"]
    assert summary["collisions"] == 0 and summary["safety_vetoes"] == 1
    # the detour keeps the robot's body clear of the box (0.25 m half size, 0.105 m robot radius)
    assert all(max(abs(x - 11.0), abs(y)) > 0.25 + 0.105 for x, y, _ in record.poses())


def test_a_start_inside_the_wall_clearance_steps_out_first(tmp_path: Path) -> None:
    # 0.15 m from the north wall (robot radius 0.105 m): a leg along the wall from here would graze it
    # and be vetoed forever; the planner first steps out to the nearest free cell.
    text = (resource_dir("scenarios") / "corridor_a.yaml").read_text()
    near_wall = text.replace("start_poses: [{x: 0, y: 0, yaw_deg: 0}]", "start_poses: [{x: 0, y: 1.85, yaw_deg: 0}]")
    assert near_wall != text
    (tmp_path / "near_wall.yaml").write_text(near_wall)
    replay = ReplayBackend(script(tmp_path / "script", [choice(1), choice(1)]))
    summary, record = drive(tmp_path, replay, scenario=str(tmp_path / "near_wall.yaml"), task_id="A5")
    assert record.poses()[0][:2] == pytest.approx([0.0, 1.85], abs=0.01)
    assert [g["outcome"] for g in record.of_type("guard")] == ["ok", "ok"]
    assert summary["outcome"] == "completed" and summary["success"] and summary["collisions"] == 0
    assert min(2.0 - y for _, y, _ in record.poses()) > 0.15 - 0.02  # never closer to the wall than at the start


def test_replaying_a_hybrid_run_reproduces_its_poses_exactly(tmp_path: Path) -> None:
    reader = MenuReader(wanting("dark brown wooden boxes", scan_first=True))
    opts: dict[str, Any] = {"scenario": "factory", "task_id": "T8", "pose": 4, "sensing": ("lidar", "detections")}
    first_summary, original = drive(tmp_path, reader, name="original", **opts)
    replay = ReplayBackend(str(tmp_path / "original"))  # strict: every request must match the recorded one
    second_summary, replayed = drive(tmp_path, replay, name="replayed", **opts)
    assert first_summary["outcome"] == second_summary["outcome"] == "completed"
    assert original.poses() == replayed.poses() and len(original.poses()) > 20
    requests = [c["request"] for c in original.of_type("llm_call")]
    assert requests == [c["request"] for c in replayed.of_type("llm_call")] and len(requests) >= 3


def test_the_neutral_menu_is_short_lines_and_the_spot_the_robot_stands_on_takes_no_place(tmp_path: Path) -> None:
    reader = MenuReader(lambda options, index: 1)
    drive(tmp_path, reader, task_text="Go to room 101", menu_order="distance", max_iterations=2)
    at_room = reader.menus[1]
    places = [text for text in at_room.values() if text.startswith("Go to ")]
    # four places to go besides the room the robot is at, which only Finish names
    assert len(places) == HybridConfig().max_landmarks == 4
    assert list(at_room.values())[-1] == "Finish (at room 101)"
    assert not any("room 101" in text for text in places)
    # one line each: a name, whole metres and one of eight directions
    line = re.compile(
        r"Go to room \d+, \d+ m (ahead|front-left|left|back-left|behind|back-right|right|front-right)(, visited)?"
    )
    assert all(line.fullmatch(text) for text in places), places


def test_a_leg_the_motion_layer_refuses_is_a_veto_of_that_decision(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The layer's own leg check refuses the first leg (as it would for something only it sees): the hybrid
    # must take the layer's word, name the veto in that decision, and plan the next leg from where the
    # robot really stands (it did not move).
    from llmnav.guard.motion import GuardedMotion
    from llmnav.guard.veto import VetoResult

    check = GuardedMotion.check_leg
    calls: list[int] = []

    def refuse_first(self: GuardedMotion, x: float, y: float) -> VetoResult:
        calls.append(1)
        if len(calls) == 1:
            return VetoResult(False, 0.3, "scripted: an obstacle only the layer sees", (0.4, 0.0))
        return check(self, x, y)

    monkeypatch.setattr(GuardedMotion, "check_leg", refuse_first)
    replay = ReplayBackend(script(tmp_path / "script", [choice(1), choice(1), choice(1)]))
    summary, record = drive(tmp_path, replay, task_text="Go to the window")
    vetoes = [g for g in record.of_type("guard") if g["outcome"] == "veto"]
    assert len(vetoes) == 1 and vetoes[0]["step"] == 1  # counted in the decision that chose the leg
    assert vetoes[0]["error"] == "scripted: an obstacle only the layer sees"
    actions = record.of_type("action")
    assert [(a["step"], a["command"], bool(a.get("vetoed"))) for a in actions] == [
        (1, "GOTO", True),
        (2, "GOTO", False),
        (3, "COMPLETE", False),
    ]
    refused, replanned = actions[0], actions[1]
    assert refused["pose_after"] == refused["pose_before"]  # the refused leg did not move the robot
    assert replanned["pose_before"] == refused["pose_after"]  # the next leg starts where the robot stands
    assert "Last: safety stop (scripted: an obstacle only the layer sees)" in user_turns(record)[1]
    assert summary["safety_vetoes"] == 1 and summary["outcome"] == "completed" and summary["success"]


def test_each_frontier_cluster_targets_its_cell_nearest_the_centroid() -> None:
    import numpy as np

    from llmnav.planners.hybrid.menu import _nearest_to_centroids

    labels = np.array(
        [
            [1, 1, 1, 0, 3],
            [0, 0, 0, 0, 3],
            [2, 0, 0, 0, 0],
        ]
    )
    targets = np.array(
        [
            [1, 0, 1, 0, 0],  # cluster 1: centroid (0, 1); its two target cells tie: the first in row order wins
            [0, 0, 0, 0, 0],  # cluster 3 has no target cell: left out
            [2, 2, 0, 0, 0],  # cluster 2: its own cell, at its centroid
        ]
    )
    assert _nearest_to_centroids(labels, targets) == [(0, 0), (2, 0)]
    assert _nearest_to_centroids(np.zeros((2, 2), dtype=int), np.zeros((2, 2), dtype=int)) == []
