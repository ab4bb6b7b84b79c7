"""Record, then strictly replay, every planner with every kind of backend: the replay must ask the same.

Backends: the embedded local model (real SmolLM2, text-only), the openai backend against the loopback test
server (multimodal: camera frames travel as data URLs), and a null policy (no model). Each cell records a
short episode under the planner's default options, replays it with `replay:<run.jsonl>` in strict mode,
and compares the final pose and every request. The loopback server answers like a model would: it hands
the request's JSON Schema and texts to `policy:keyword`, so its answers are valid for every planner.
The README's own run (`llmnav drive --task "Go to room 101"`, default local backend) is tested through
the CLI, as a user types it.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from llmnav.backends.base import ChatRequest, Message
from llmnav.backends.policy import PolicyBackend
from llmnav.cli import app
from llmnav.planners.base import drive_options
from llmnav.runs.runlog import read_run
from llmnav.runs.runner import EpisodeSpec, run_episode

# One short episode per planner, under its default options: only the length is cut.
EPISODES: dict[str, dict[str, Any]] = {
    "hybrid": {"scenario": "corridor_a", "task_text": "Go to room 101", "options": {"max_iterations": 3}},
    # The hybrid scores options where the backend can (policy, local); this cell asks it to generate.
    "hybrid-generate": {
        "planner": "hybrid",
        "scenario": "corridor_a",
        "task_text": "Go to room 101",
        "options": {"max_iterations": 3, "decide": "generate"},
    },
    "stepwise": {"scenario": "corridor_a", "task_text": "Go to room 101", "options": {"max_iterations": 2}},
    "waypoints": {"scenario": "corridor_a", "task_text": "Go to room 101", "options": {}},
    # The FSM talks to a model only with --assist llm; without it there would be nothing to replay.
    "fsm": {"scenario": "maze_arena", "task_id": "M1", "options": {"assist": "llm", "max_ticks": 400}},
}
# Cells the local model makes too slow for the default suite (long stepwise prompts, several waypoint
# generations); hybrid × local runs in the default suite as the README run below.
SLOW_LOCAL = {"stepwise", "waypoints", "hybrid", "hybrid-generate"}


def _answer_with_policy(server: Any) -> None:
    """The loopback server answers each chat completion with `policy:keyword`'s choice."""
    policy = PolicyBackend("keyword")

    def answer(seen: Any) -> Any:
        if seen.path == "/tokenize":  # a server that only generates (one whose /tokenize failed would abort)
            return server.reply(404, {"error": {"message": "File Not Found"}})
        body = seen.body
        messages = []
        for m in body["messages"]:
            content = m["content"]
            text = content if isinstance(content, str) else "\n".join(p["text"] for p in content if "text" in p)
            messages.append(Message(m["role"], text))
        schema = (body.get("response_format") or {}).get("json_schema", {}).get("schema")
        reply = policy.chat(ChatRequest(tuple(messages), schema))
        return server.reply(
            200,
            {
                "model": "loopback",
                "choices": [{"message": {"role": "assistant", "content": reply.text}, "finish_reason": "stop"}],
                "usage": {"prompt_tokens": 10, "completion_tokens": 5},
            },
        )

    server.default = answer


def _episode(planner: str, backend: str, out: Path) -> dict[str, Any]:
    setup = EPISODES[planner]
    spec = EpisodeSpec(
        scenario=setup["scenario"],
        task_id=setup.get("task_id"),
        task_text=setup.get("task_text"),
        options=drive_options(planner=setup.get("planner", planner), **setup["options"]),  # type: ignore[arg-type]
        backend=backend,
        out_dir=out,
        plots=False,
    )
    return run_episode(spec)


def _requests(run_dir: Path) -> list[dict[str, Any]]:
    return [call["request"] for call in read_run(run_dir).of_type("llm_call")]


def _record_and_replay(planner: str, backend: str, tmp_path: Path) -> dict[str, Any]:
    first = _episode(planner, backend, tmp_path / "rec")
    again = _episode(planner, f"replay:{tmp_path / 'rec' / 'run.jsonl'}", tmp_path / "rep")
    assert "differs" not in again["reason"], again["reason"]
    assert again["outcome"] == first["outcome"], (first["reason"], again["reason"])
    assert again["final_pose"] == first["final_pose"]
    recorded, replayed = _requests(tmp_path / "rec"), _requests(tmp_path / "rep")
    assert recorded and replayed == recorded
    config = read_run(tmp_path / "rec").config
    assert read_run(tmp_path / "rep").config["modality"] == config["modality"]
    return config


def _cells() -> list[Any]:
    cells = []
    for planner in EPISODES:
        for kind in ("policy", "http", "local"):
            marks = [pytest.mark.slow] if kind == "local" and planner in SLOW_LOCAL else []
            cells.append(pytest.param(planner, kind, marks=marks, id=f"{planner}-{kind}"))
    return cells


@pytest.mark.parametrize(("planner", "kind"), _cells())
def test_record_then_strict_replay(planner: str, kind: str, tmp_path: Path, request: Any) -> None:
    if kind == "http":
        server = request.getfixturevalue("server")
        assert server.url.startswith("http://127.0.0.1:")
        _answer_with_policy(server)
        backend = f"openai:loopback@{server.url}/v1"
    else:
        backend = {"policy": "policy:keyword", "local": "local"}[kind]
    config = _record_and_replay(planner, backend, tmp_path)
    assert config["modality"] == ("multimodal" if kind == "http" else "text")
    if kind == "http" and planner in ("hybrid", "hybrid-generate", "stepwise"):  # the camera frame went to the model
        assert config["attachments"] == ["camera image 640x480 JPEG"]
        assert any(m.get("images") for r in _requests(tmp_path / "rec") for m in r["messages"])


def test_the_readme_run_replays_strictly(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    cli = CliRunner()
    first = cli.invoke(app, ["drive", "--task", "Go to room 101", "--out", "rec", "--json"])
    assert first.exception is None or isinstance(first.exception, SystemExit), first.output
    recorded = json.loads(first.stdout)
    again = cli.invoke(
        app, ["drive", "--task", "Go to room 101", "--backend", "replay:rec/run.jsonl", "--out", "rep", "--json"]
    )
    replayed = json.loads(again.stdout)
    assert again.exit_code == first.exit_code, again.output
    assert "differs" not in replayed["reason"], replayed["reason"]
    assert replayed["final_pose"] == recorded["final_pose"] and replayed["outcome"] == recorded["outcome"]
    assert _requests(tmp_path / "rep") == _requests(tmp_path / "rec") != []
    assert read_run(tmp_path / "rec").config["modality"] == "text"  # the local model reads no images


def test_the_recorded_modality_decides_what_replay_attaches(tmp_path: Path) -> None:
    # A text-only recording claimed as multimodal: the replayed hybrid now attaches the camera frame,
    # and strict replay must notice (this is how the README run used to fail).
    _episode("hybrid-generate", "policy:first", tmp_path / "rec")
    log = tmp_path / "rec" / "run.jsonl"
    lines = log.read_text().splitlines()
    config = json.loads(lines[0])
    assert config["modality"] == "text"
    log.write_text("\n".join([json.dumps(config | {"modality": "multimodal"}), *lines[1:]]) + "\n")
    again = _episode("hybrid-generate", f"replay:{log}", tmp_path / "rep")
    assert again["outcome"] == "aborted" and "message 2 (user) differs" in again["reason"]
