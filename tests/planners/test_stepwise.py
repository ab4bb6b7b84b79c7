"""The stepwise planner (source A) with scripted answers: guard corrections, safety veto, self-check,
history windows, max iterations, exact replay, and a run killed mid-episode."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from llmnav.backends.replay import ReplayBackend, write_script
from llmnav.guard.parse import correction_message, parse_answer
from llmnav.guard.schemas import response_schema
from llmnav.planners.base import drive_options
from llmnav.planners.stepwise.answers import ActionBounds, StepAction, step_answer
from llmnav.runs.runlog import RunRecord, read_run
from llmnav.runs.runner import EpisodeSpec, exit_code, run_episode
from llmnav.scoring.metrics import summarize_run
from llmnav.world.scenario import load_scenario

SMALL = str(Path(__file__).parents[1] / "runner" / "small_room.yaml")
TASK = "Go to the red box"


def answer(command: str, parameters: float) -> str:
    return f"```json\n{json.dumps(step_answer(command, parameters, reasoning=f'{command} looks right'))}\n```"


def script(path: Path, replies: list[str]) -> str:
    """Scripted replies the replay backend returns in order, whatever the prompt."""
    return write_script(path, replies, purpose="action", latency_s=0.25)


def drive(
    tmp_path: Path,
    replies: list[str] | None,
    *,
    backend: str | None = None,
    pose: int = 1,
    name: str = "run",
    **options: Any,
) -> tuple[dict[str, Any], RunRecord]:
    options.setdefault("sensing", ("lidar",))
    replay = ReplayBackend(backend or script(tmp_path / f"{name}-script", replies or []))
    spec = EpisodeSpec(
        scenario=SMALL,
        task_id="T1",
        task_text=None,
        start_pose=pose,
        options=drive_options(planner="stepwise", **options),
        backend=replay.spec,
        out_dir=tmp_path / name,
    )
    summary = run_episode(spec, backend_obj=replay)
    return summary, read_run(tmp_path / name)


def calls(record: RunRecord) -> list[dict[str, Any]]:
    return record.of_type("llm_call")


def test_malformed_json_gets_a_correction_turn_with_the_exact_error(tmp_path: Path) -> None:
    bad = '{"goal": "x", "action": {"command": "FRONT"'  # truncated
    summary, record = drive(
        tmp_path, ["I think we should go left", bad, answer("ROTATE_LEFT", 30), answer("COMPLETE", 0)]
    )
    assert summary["outcome"] == "completed" and not summary["success"] and exit_code(summary) == 1
    assert [c["purpose"] for c in calls(record)] == ["action", "correction", "correction", "action"]
    guards = record.of_type("guard")
    assert [(g["step"], g["outcome"], g["attempt"]) for g in guards] == [
        (1, "parse", 1),
        (1, "schema", 2),
        (1, "ok", 3),
        (2, "ok", 1),
    ]
    bounds = ActionBounds(max_step_m=drive_options("stepwise").max_step_m)
    schema = response_schema(StepAction)
    first = calls(record)[1]["request"]["messages"]
    assert first[-2] == {"role": "assistant", "text": "I think we should go left"}
    assert first[-1]["text"] == correction_message(
        parse_answer("I think we should go left", StepAction, bounds=bounds), schema
    )
    second = calls(record)[2]["request"]["messages"]
    assert second[-1]["text"] == correction_message(parse_answer(bad, StepAction, bounds=bounds), schema)
    assert guards[1]["error"] in second[-1]["text"]
    assert summary["json_errors"] == 2 and summary["iterations"] == 2
    actions = record.of_type("action")
    assert [a["command"] for a in actions] == ["ROTATE_LEFT", "COMPLETE"]
    turned = actions[0]["pose_after"][2] - actions[0]["pose_before"][2]
    assert math.degrees(turned) == pytest.approx(30.0, abs=1.0)
    # the request carries the action's JSON Schema for constrained decoding
    assert calls(record)[0]["request"]["json_schema"] == schema


def test_a_front_into_a_wall_is_vetoed_and_the_alternative_accepted(tmp_path: Path) -> None:
    # start pose 2 faces the east wall 2.3 m away: a 2 m move cannot stop in time with a 0.72 m wide base
    summary, record = drive(tmp_path, [answer("FRONT", 2.0), answer("ROTATE_LEFT", 90), answer("COMPLETE", 0)], pose=2)
    assert summary["outcome"] == "completed"
    assert [g["outcome"] for g in record.of_type("guard")] == ["ok", "veto", "ok", "ok"]
    assert [c["purpose"] for c in calls(record)] == ["action", "veto", "action"]
    veto_turn = calls(record)[1]["request"]["messages"][-1]["text"]
    assert veto_turn.startswith("Safety check") and "FRONT 2.00 m" in veto_turn
    actions = record.of_type("action")
    assert [a["command"] for a in actions] == ["ROTATE_LEFT", "COMPLETE"]
    assert actions[0]["pose_after"][0] == pytest.approx(5.5, abs=0.02)  # it never drove into the wall
    assert summary["safety_vetoes"] == 1 and summary["collisions"] == 0


def test_vetoes_beyond_the_budget_abort_the_episode(tmp_path: Path) -> None:
    summary, record = drive(tmp_path, [answer("FRONT", 2.0), answer("FRONT", 3.0)], pose=2, max_vetoes=1)
    assert summary["outcome"] == "aborted" and exit_code(summary) == 3  # a model failure
    assert summary["reason"].startswith("safety veto: every proposed motion was blocked (1 vetoes)")
    assert [g["outcome"] for g in record.of_type("guard")] == ["ok", "veto", "ok", "veto"]
    assert record.of_type("action") == []


def test_corrections_beyond_the_budget_abort(tmp_path: Path) -> None:
    summary, _ = drive(tmp_path, ["no", "still no"], max_corrections=1)
    assert summary["outcome"] == "aborted" and "no valid action after 1 correction turns" in summary["reason"]


@pytest.mark.parametrize("history", ["0", "1", "2", "all"])
def test_history_modes_send_exactly_the_window(tmp_path: Path, history: str) -> None:
    replies = [answer("ROTATE_LEFT", 20 + i) for i in range(4)]
    summary, record = drive(tmp_path, replies, history=history, max_iterations=4)
    assert summary["outcome"] == "failed" and summary["reason"].startswith("max iterations (4)")
    requests = [c["request"]["messages"] for c in calls(record)]
    assert len(requests) == 4
    current = [r[-1] for r in requests]  # each step's own user turn
    k = 99 if history == "all" else int(history)
    for step, messages in enumerate(requests, start=1):
        kept = min(step - 1, k)
        expected = [requests[0][0]]  # the same system prompt every time
        for j in range(step - 1 - kept, step - 1):
            expected += [current[j], {"role": "assistant", "text": replies[j]}]
        expected.append(current[step - 1])
        assert messages == expected, (history, step)
        assert messages[0]["role"] == "system"
        # the task is stated in the first turn, and again whenever the window no longer holds that turn
        states_task = current[step - 1]["text"].startswith(f"Task: {TASK}")
        assert states_task == (step == 1 or step - 1 > k), (history, step)
        assert "LiDAR" in current[step - 1]["text"]


def test_self_check_confirms_or_revises(tmp_path: Path) -> None:
    replies = [
        answer("ROTATE_LEFT", 30),
        "CONFIRMED",
        answer("ROTATE_LEFT", 45),
        "Not quite.\n" + answer("ROTATE_RIGHT", 10),
        answer("COMPLETE", 0),
        "CONFIRMED",
    ]
    summary, record = drive(tmp_path, replies, self_check=True)
    assert summary["outcome"] == "completed"
    assert [c["purpose"] for c in calls(record)] == ["action", "self_check"] * 3
    check_turn = calls(record)[1]["request"]["messages"][-1]["text"]
    assert "CONFIRMED" in check_turn and calls(record)[1]["request"]["json_schema"] is None
    assert [(a["command"], a["parameters"]) for a in record.of_type("action")] == [
        ("ROTATE_LEFT", 30),
        ("ROTATE_RIGHT", 10),
        ("COMPLETE", 0),
    ]
    # a confirmed answer enters the history as the original answer
    assert calls(record)[2]["request"]["messages"][2] == {"role": "assistant", "text": replies[0]}
    assert summary["planner_metrics"]["self_check_revisions"] == 1


def test_replaying_a_run_reproduces_its_poses_exactly(tmp_path: Path) -> None:
    replies = [answer("FRONT", 1.0), answer("ROTATE_RIGHT", 60), answer("FRONT", 1.2), answer("COMPLETE", 0)]
    first, rec1 = drive(
        tmp_path, replies, name="original", sensing=("lidar", "image"), image_width=160, image_height=120
    )
    # strict replay: every request must equal the recorded one, images included
    second, rec2 = drive(
        tmp_path,
        None,
        backend=str(tmp_path / "original"),
        name="replayed",
        sensing=("lidar", "image"),
        image_width=160,
        image_height=120,
    )
    assert first["outcome"] == second["outcome"] == "completed"
    assert rec1.poses() == rec2.poses() and len(rec1.poses()) > 10
    assert [c["request"] for c in calls(rec1)] == [c["request"] for c in calls(rec2)]
    assert any(m.get("images") for c in calls(rec1) for m in c["request"]["messages"])
    assert len(list((tmp_path / "original" / "images").glob("*.jpg"))) >= 3


_KILL_SCRIPT = """
import sys, time
from pathlib import Path
from llmnav.backends.base import Backend, ChatResult
from llmnav.planners.base import drive_options
from llmnav.runs.runner import EpisodeSpec, run_episode

class Slow(Backend):
    name = "slow"
    def chat(self, request):
        time.sleep(0.2)
        text = '{"goal": "g", "reasoning": "r", "scene_description": "s", '
        text += '"action": {"command": "ROTATE_LEFT", "parameters": 40}}'
        return ChatResult(text=text, latency_s=0.2, model="slow")

spec = EpisodeSpec(scenario=sys.argv[1], task_id="T1", task_text=None, start_pose=1,
                   options=drive_options(planner="stepwise", sensing=("lidar",), max_iterations=500),
                   backend="slow", out_dir=Path(sys.argv[2]))
run_episode(spec, backend_obj=Slow())
"""


def test_a_run_killed_mid_episode_leaves_a_readable_log(tmp_path: Path) -> None:
    run_dir = tmp_path / "killed"
    proc = subprocess.Popen(
        [sys.executable, "-c", _KILL_SCRIPT, SMALL, str(run_dir)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            log = run_dir / "run.jsonl"
            if log.exists() and log.read_text().count('"type": "action"') >= 3:
                break
            time.sleep(0.05)
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait(timeout=10)
    assert proc.returncode == -signal.SIGKILL
    record = read_run(run_dir)
    assert not record.complete and len(record.of_type("action")) >= 3
    summary = summarize_run(record, load_scenario(SMALL))
    assert summary["cut_short"] is True and summary["outcome"] == "aborted"
    assert summary["rotation_total_rad"] > math.radians(100)


def test_a_collision_the_lidar_cannot_see_is_reported_with_the_next_observation(tmp_path: Path) -> None:
    # a shelf board at 0.6-1.0 m passes above the LiDAR plane (0.28 m) but not above the 1.2 m tall robot
    import yaml

    data = yaml.safe_load(Path(SMALL).read_text())
    data["obstacles"] = [{"id": "shelf", "center": [3.0, 3.0], "size": [0.4, 2.0], "z": 0.6, "height": 0.4}]
    scenario = tmp_path / "overhang.yaml"
    scenario.write_text(yaml.safe_dump(data))
    replay = ReplayBackend(script(tmp_path / "script", [answer("FRONT", 2.0), answer("COMPLETE", 0)]))
    spec = EpisodeSpec(
        scenario=str(scenario),
        task_id="T1",
        task_text=None,
        start_pose=1,
        options=drive_options(planner="stepwise", sensing=("lidar",)),
        backend=replay.spec,
        out_dir=tmp_path / "run",
    )
    summary = run_episode(spec, backend_obj=replay)
    record = read_run(tmp_path / "run")
    first = record.of_type("action")[0]
    assert first["collided"] and first["collision_with"] == "shelf" and first["stopped_reason"] == "collision"
    assert 0.3 < first["distance_m"] < 1.5
    told = calls(record)[1]["request"]["messages"][-1]["text"]
    assert told.startswith(
        f"Your last action (FRONT 2 m) was stopped after {first['distance_m']:.2f} m by a collision with shelf."
    )
    assert summary["collisions"] == 1 and summary["planner_metrics"]["collisions"] == 1
