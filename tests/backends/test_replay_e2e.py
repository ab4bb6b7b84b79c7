"""Record a real episode through the openai backend (loopback server), then replay it with the runner.

The replayed run must reproduce the recorded metrics exactly (latency included); a changed prompt setting
must stop a strict replay with the call and step named, and loose mode must carry on.
"""

from __future__ import annotations

import json

from llmnav.planners.base import DriveOptions, drive_options
from llmnav.planners.stepwise.answers import step_answer
from llmnav.runs.runner import EpisodeSpec, run_episode

ANSWERS = [
    {"command": "ROTATE_LEFT", "parameters": 30},
    {"command": "FRONT", "parameters": 0.5},
    {"command": "COMPLETE", "parameters": 0},
]
# what the run's own backend decides: a replay asks no server, so it costs nothing
RUN_SPECIFIC = {"backend", "condition", "wall_time_s", "run_dir", "trajectory", "cost_usd", "cost_note"}


def options(**changes: object) -> DriveOptions:
    return drive_options(planner="stepwise", max_iterations=4, image_width=160, image_height=120, **changes)


def _answer_server(server) -> None:
    calls = {"n": 0}

    def answer(seen):
        action = ANSWERS[min(calls["n"], len(ANSWERS) - 1)]
        calls["n"] += 1
        content = json.dumps(step_answer(action["command"], action["parameters"]))
        return server.reply(
            200,
            {
                "model": "fake",
                "choices": [{"message": {"role": "assistant", "content": content}, "finish_reason": "stop"}],
                "usage": {"prompt_tokens": 50, "completion_tokens": 9},
            },
        )

    server.default = answer


def test_replay_reproduces_a_recorded_episode(server, tmp_path, monkeypatch):
    monkeypatch.delenv("OPENAI_API_KEY", raising=False)
    _answer_server(server)
    first = run_episode(
        EpisodeSpec(
            scenario="",
            task_id="T1",
            options=options(),
            backend=f"openai:fake@{server.url}/v1",
            out_dir=tmp_path / "rec",
        )
    )
    assert first["outcome"] == "completed" and first["llm_calls"] == 3

    again = run_episode(
        EpisodeSpec(
            scenario="",
            task_id="T1",
            options=options(),
            backend=f"replay:{tmp_path / 'rec'}",
            out_dir=tmp_path / "rep",
        )
    )
    for key in set(first) - RUN_SPECIFIC:
        assert again[key] == first[key], key
    assert len(server.seen) == 3  # the replay never touched the server

    changed = run_episode(
        EpisodeSpec(
            scenario="",
            task_id="T1",
            options=options(lidar_sectors=4),
            backend=f"replay:{tmp_path / 'rec'}",
            out_dir=tmp_path / "div",
        )
    )
    assert changed["outcome"] == "aborted"
    assert "replay: call 1 (step" in changed["reason"] and "differs from the recording" in changed["reason"]

    loose = run_episode(
        EpisodeSpec(
            scenario="",
            task_id="T1",
            options=options(lidar_sectors=4),
            backend=f"replay:{tmp_path / 'rec'}?loose",
            out_dir=tmp_path / "loose",
        )
    )
    assert loose["outcome"] == "completed" and loose["llm_calls"] == 3
