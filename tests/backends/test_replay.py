"""Replay backend: recorded replies in order, strict divergence detection, loose mode, broken files."""

from __future__ import annotations

import base64
import json
from pathlib import Path

import pytest

from llmnav.backends.base import ChatRequest, ChatResult, Image, Message
from llmnav.backends.replay import ReplayBackend
from llmnav.errors import BackendSpecError, BadInputError, ModelError, ReplayDivergenceError
from llmnav.runs.runlog import RunLog

IMG = Image(base64.b64encode(b"\xff\xd8\xff\xe0replay-frame").decode())
SCHEMA = {"type": "object", "properties": {"command": {"type": "string"}}}
SYSTEM = Message("system", "You steer a robot.\nAnswer in JSON.")


def request(step: int, note: str = "") -> ChatRequest:
    text = f"Step {step}: front clearance 1.{step} m.{note}\nWhat next?"
    return ChatRequest((SYSTEM, Message("user", text, (IMG,))), json_schema=SCHEMA, seed=step)


def reply(step: int) -> ChatResult:
    return ChatResult(
        f'{{"command": "FRONT", "step": {step}}}',
        latency_s=0.5 + step,
        model="llava:7b",
        prompt_tokens=100 + step,
        completion_tokens=10 + step,
        meta={"attempts": 1},
    )


@pytest.fixture
def run_dir(tmp_path: Path) -> Path:
    """A run log with three model calls (steps 0, 1, 2) and a recorded failure at step 3."""
    folder = tmp_path / "run-1"
    config = {"planner": "stepwise", "backend": "ollama:llava:7b", "modality": "multimodal"}
    with RunLog(folder, config) as log:
        for step in range(3):
            log.event("observation", step=step, image=log.image(IMG))
            req = request(step)
            log.event("llm_call", step=step, purpose="action", request=req.to_log(), reply=reply(step).to_log())
            log.event("action", step=step, command="FRONT", parameters=0.5)
        log.event("llm_call", step=3, purpose="action", request=request(3).to_log(), error="ollama: HTTP 500 boom")
        log.event("end", outcome="aborted", reason="model error")
    return folder


def test_replies_in_order_with_recorded_latency(run_dir):
    backend = ReplayBackend(str(run_dir))
    assert backend.deterministic and len(backend.calls) == 4
    for step in range(3):
        result = backend.chat(request(step))
        expected = reply(step)
        assert result.text == expected.text
        assert result.latency_s == pytest.approx(expected.latency_s)
        assert (result.prompt_tokens, result.completion_tokens) == (
            expected.prompt_tokens,
            expected.completion_tokens,
        )
        assert result.model == "llava:7b" and result.meta == {"attempts": 1}
    with pytest.raises(ModelError, match="recorded failure of call 4: ollama: HTTP 500 boom"):
        backend.chat(request(3))
    with pytest.raises(ModelError) as info:
        backend.chat(request(4))
    assert "holds 4 model calls" in str(info.value) and "call 5" in str(info.value)
    assert "\n" not in str(info.value)


def test_accepts_the_jsonl_file_itself(run_dir):
    backend = ReplayBackend(str(run_dir / "run.jsonl"))
    assert backend.chat(request(0)).text == reply(0).text
    assert backend.remaining == 3


def test_strict_divergence_names_call_and_step_with_diff(run_dir):
    backend = ReplayBackend(str(run_dir))
    backend.chat(request(0))
    with pytest.raises(ReplayDivergenceError) as info:
        backend.chat(request(1, note=" A new obstacle."))
    lines = str(info.value).splitlines()
    assert "call 2 (step 1, action)" in lines[0] and "message 2 (user) differs" in lines[0]
    assert "run.jsonl:" in lines[0]
    assert any(line.startswith("-Step 1: front clearance 1.1 m.") for line in lines[1:])
    assert any(line.startswith("+") and "A new obstacle." in line for line in lines[1:])
    assert len(lines) <= 10


def test_divergence_in_options_is_reported(run_dir):
    backend = ReplayBackend(str(run_dir))
    changed = ChatRequest(request(0).messages, json_schema=SCHEMA, seed=0, temperature=0.7)
    with pytest.raises(ReplayDivergenceError, match=r"call 1 \(step 0, action\).*temperature differs"):
        backend.chat(changed)


def test_different_image_is_a_divergence(run_dir):
    other = Image(base64.b64encode(b"\xff\xd8\xff\xe0another-frame").decode())
    req = ChatRequest((SYSTEM, Message("user", request(0).messages[1].text, (other,))), json_schema=SCHEMA, seed=0)
    with pytest.raises(ReplayDivergenceError):
        ReplayBackend(str(run_dir)).chat(req)


@pytest.mark.parametrize("how", ["spec", "option"])
def test_loose_mode_continues(run_dir, how):
    backend = ReplayBackend(f"{run_dir}?loose") if how == "spec" else ReplayBackend(str(run_dir), loose=True)
    first = backend.chat(request(0, note=" changed"))
    second = backend.chat(request(1))
    assert first.text == reply(0).text and first.meta["replay_diverged"] is True
    assert second.text == reply(1).text and "replay_diverged" not in second.meta
    assert backend.divergences == 1


def test_bad_arguments():
    with pytest.raises(BackendSpecError, match="replay needs a run"):
        ReplayBackend()
    with pytest.raises(BackendSpecError, match="unknown flag 'fast'"):
        ReplayBackend("somewhere?fast")
    with pytest.raises(BackendSpecError, match="loose"):
        ReplayBackend("somewhere", loos=True)


def test_missing_file_is_bad_input(tmp_path):
    with pytest.raises(BadInputError, match="cannot read"):
        ReplayBackend(str(tmp_path / "nothing-here"))


def test_hand_edited_broken_line(run_dir):
    path = run_dir / "run.jsonl"
    lines = path.read_text().splitlines()
    lines[2] = lines[2][:40] + "<<oops>>"  # an llm_call line mangled in an editor
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(BadInputError) as info:
        ReplayBackend(str(run_dir))
    message = str(info.value)
    assert "\n" not in message and str(path) in message and "line 3" in message


def test_llm_call_without_reply_or_error(run_dir):
    path = run_dir / "run.jsonl"
    lines = path.read_text().splitlines()
    event = json.loads(lines[2])
    assert event["type"] == "llm_call"
    del event["reply"]
    lines[2] = json.dumps(event)
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(BadInputError, match=r"line 3: llm_call has neither reply nor error"):
        ReplayBackend(str(run_dir))


def test_reply_without_text(run_dir):
    path = run_dir / "run.jsonl"
    lines = path.read_text().splitlines()
    event = json.loads(lines[2])
    event["reply"] = {"latency_s": 1.0}
    lines[2] = json.dumps(event)
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(BadInputError, match="line 3: llm_call reply has no text"):
        ReplayBackend(str(run_dir))


def test_torn_last_line_of_a_killed_run_is_ignored(run_dir):
    path = run_dir / "run.jsonl"
    text = path.read_text()
    path.write_text(text + '{"type": "llm_call", "step": 9, "requ')  # killed mid-write
    assert len(ReplayBackend(str(run_dir)).calls) == 4


def test_status(run_dir, tmp_path):
    assert ReplayBackend.status().ready
    good = ReplayBackend.status(str(run_dir))
    assert good.ready and "4 recorded model calls" in good.detail
    bad = ReplayBackend.status(str(tmp_path / "nope"))
    assert not bad.ready and "cannot read" in bad.detail


def test_modality_comes_from_the_recording(run_dir, tmp_path):
    assert ReplayBackend(str(run_dir)).multimodal is True
    text_only = tmp_path / "text-only"
    with RunLog(text_only, {"planner": "hybrid", "backend": "local", "modality": "text"}) as log:
        log.event("llm_call", step=1, request=request(1).to_log(), reply=reply(1).to_log())
    assert ReplayBackend(str(text_only)).multimodal is False


def test_an_older_log_without_modality_names_what_is_missing(tmp_path):
    old = tmp_path / "old"
    with RunLog(old, {"planner": "hybrid", "backend": "local"}) as log:
        log.event("llm_call", step=1, request=request(1).to_log(), reply=reply(1).to_log())
    with pytest.raises(BadInputError) as err:
        ReplayBackend(str(old))
    message = str(err.value)
    assert "older llmnav" in message and "'modality'" in message and "\n" not in message
    assert ReplayBackend(f"{old}?loose").multimodal is True  # loose mode answers in order anyway


def test_an_unknown_modality_is_bad_input(tmp_path):
    odd = tmp_path / "odd"
    with RunLog(odd, {"modality": "telepathy"}) as log:
        log.event("llm_call", step=1, request=request(1).to_log(), reply=reply(1).to_log())
    with pytest.raises(BadInputError, match="'telepathy'"):
        ReplayBackend(str(odd))


def test_an_older_log_on_the_command_line_is_one_line_exit_2(tmp_path):
    from typer.testing import CliRunner

    from llmnav.cli import app

    old = tmp_path / "old"
    with RunLog(old, {"planner": "hybrid", "backend": "local"}) as log:
        log.event("llm_call", step=1, request=request(1).to_log(), reply=reply(1).to_log())
    result = CliRunner().invoke(
        app, ["drive", "--task", "Go to room 101", "--backend", f"replay:{old}", "--out", str(tmp_path / "r")]
    )
    assert result.exit_code == 2 and result.stdout == ""
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "'modality'" in lines[0] and "older llmnav" in lines[0]
    assert not (tmp_path / "r").exists()
