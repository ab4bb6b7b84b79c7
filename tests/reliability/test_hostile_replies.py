"""Hostile replies: a server's reply is data. Odd types in any field (`"usage": [1, 2]`), negative or absurd
token counts, and log-probabilities that are NaN, infinite, positive or beyond the per-token floor end the
call with a one-line `ModelError`, never a traceback, a decision or a tabled score; a replay file holding
such values is refused with one line. Counted as category "hostile replies".
"""

from __future__ import annotations

import json
import math
import traceback
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from llmnav.backends.base import ChatRequest, Message, ScoreRequest, get_backend
from llmnav.backends.replay import ReplayBackend
from llmnav.cli import app
from llmnav.errors import BadInputError, ModelError
from llmnav.runs.runlog import RunLog

CATEGORY = "hostile replies"
SMALL_ROOM = str(Path(__file__).parents[1] / "runner" / "small_room.yaml")
FAST = {"max_retries": 0, "timeout_s": 2.0, "connect_timeout_s": 1.0}
ASK = ChatRequest(messages=(Message("user", "hello"),))


def chat_body(backend: str, text: str = "hi", **odd: Any) -> dict[str, Any]:
    """A well-formed chat reply of each provider, with some fields replaced (`odd`: field → value)."""
    if backend == "openai":
        body: dict[str, Any] = {
            "model": "m",
            "choices": [{"message": {"role": "assistant", "content": text}, "finish_reason": "stop"}],
            "usage": {"prompt_tokens": 3, "completion_tokens": 1},
        }
    elif backend == "gemini":
        body = {
            "candidates": [{"content": {"role": "model", "parts": [{"text": text}]}, "finishReason": "STOP"}],
            "usageMetadata": {"promptTokenCount": 3, "candidatesTokenCount": 1},
            "modelVersion": "g",
        }
    else:
        body = {"model": "m", "message": {"role": "assistant", "content": text}, "done": True,
                "prompt_eval_count": 3, "eval_count": 1, "eval_duration": 1000}  # fmt: skip
    body.update(odd)
    return body


# provider → (field, hostile value) cases; every one must be a ModelError naming the field
HOSTILE: dict[str, list[tuple[str, Any]]] = {
    "openai": [("usage", [1, 2]), ("usage", "12"), ("usage", {"prompt_tokens": -5}),
               ("usage", {"completion_tokens": 1e30}), ("usage", {"prompt_tokens": True}),
               ("choices", {"0": 1}), ("choices", [["x"]]), ("model", {"a": 1})],
    "gemini": [("usageMetadata", [1, 2]), ("usageMetadata", {"promptTokenCount": -1}),
               ("candidates", {"a": 1}), ("candidates", [{"content": [1]}]), ("promptFeedback", [1]),
               ("modelVersion", 7)],
    "ollama": [("prompt_eval_count", -3), ("eval_count", "7"), ("eval_duration", -1), ("eval_duration", 1e400),
               ("done_reason", ["stop"]), ("model", 1)],
}  # fmt: skip
CASES = [(backend, key, value) for backend, pairs in HOSTILE.items() for key, value in pairs]


def spec_for(backend: str, url: str, monkeypatch: pytest.MonkeyPatch) -> str:
    monkeypatch.setenv("GEMINI_API_KEY", "AIzaFAKE-replies-0123456789")
    monkeypatch.setenv("LLMNAV_GEMINI_BASE_URL", url)
    monkeypatch.setenv("OLLAMA_HOST", url)
    monkeypatch.delenv("OPENAI_API_KEY", raising=False)
    return {"openai": f"openai:m@{url}/v1", "gemini": "gemini:gemini-2.0-flash", "ollama": "ollama:m"}[backend]


@pytest.mark.parametrize(("backend", "key", "value"), CASES, ids=[f"{b}-{k}-{json.dumps(v)}" for b, k, v in CASES])
def test_an_odd_field_is_a_one_line_model_error(
    backend: str, key: str, value: Any, server: Any, monkeypatch: Any, tally: Any
) -> None:
    tally.add(CATEGORY, tried=1)
    client = get_backend(spec_for(backend, server.url, monkeypatch), **FAST)
    try:
        server.default = server.reply(200, chat_body(backend))  # the same reply, well formed, is read
        good = client.chat(ASK)
        assert (good.text, good.prompt_tokens, good.completion_tokens) == ("hi", 3, 1)
        odd = {key: value, **({"candidates": []} if key == "promptFeedback" else {})}
        server.default = server.reply(200, chat_body(backend, **odd))
        try:
            client.chat(ASK)
        except ModelError as err:
            assert "\n" not in str(err) and key in str(err) or "no " in str(err), str(err)
        except Exception as err:  # the failure this test is about: a traceback
            tally.add(CATEGORY, crashes=1)
            raise AssertionError("".join(traceback.format_exception(err))) from None
        else:
            tally.add(CATEGORY, failures=1)
            raise AssertionError(f"{backend} accepted {key}={value!r}")
    finally:
        client.close()


def test_a_drive_against_a_list_usage_ends_with_one_line(tmp_path: Path, server: Any, tally: Any) -> None:
    """The issue's repro: `"usage": [1, 2]` gave `AttributeError: 'list' object has no attribute 'get'`."""
    tally.add(CATEGORY, tried=1)
    server.default = server.reply(200, chat_body("openai", usage=[1, 2]))
    result = CliRunner().invoke(
        app, ["drive", "--planner", "stepwise", "--backend", f"openai:m@{server.url}/v1", "--scenario", SMALL_ROOM,
              "--task-id", "T1", "--sensing", "lidar", "--out", str(tmp_path / "run"), "--json"]
    )  # fmt: skip
    crashed = result.exception is not None and not isinstance(result.exception, SystemExit)
    tally.add(CATEGORY, crashes=int(crashed))
    assert not crashed, "".join(traceback.format_exception(result.exception)) if crashed else ""
    assert result.exit_code != 0 and "usage" in result.output and "Traceback" not in result.output, result.output


def llama_server(server: Any, logprob: Any, ids: Any = None) -> None:
    """A llama.cpp-like server: `/tokenize` gives one id per character, `/completions` the forced tokens
    back, each with `logprob` (and `ids` instead of the forced ones when given)."""

    def answer(seen: Any) -> Any:
        if seen.path.endswith("/tokenize"):
            return server.reply(200, {"tokens": [ord(c) for c in seen.body["content"]]})
        forced = [int(x) for x in seen.body["grammar"].split("start:")[1].replace("<[", " ").replace("]>", " ").split()]
        content = [{"id": t, "token": str(t), "logprob": logprob} for t in (forced if ids is None else ids)]
        return server.reply(200, {"choices": [{"text": "", "logprobs": {"content": content}}]})

    server.default = answer


def raw_number(text: str) -> Any:
    """A JSON number the test server writes as is (`NaN`, `1e400`): json.dumps writes floats, this a token."""
    return json.loads(text)


BAD_LOGPROBS = ["NaN", "Infinity", "-Infinity", "1e308", "-1e308", "40.0", "0.5", '"nan"', '"-1.0"', "true", "null",
                "-5000.0"]  # fmt: skip


@pytest.mark.parametrize("value", BAD_LOGPROBS)
def test_a_scoring_reply_with_an_unbelievable_log_probability_is_a_model_error(
    value: str, server: Any, tally: Any
) -> None:
    tally.add(CATEGORY, tried=1)
    client = get_backend(f"openai:m@{server.url}/v1", **FAST)
    request = ScoreRequest("Go to the", (" box", " fire"))
    try:
        llama_server(server, -0.25)
        assert [s.logprob for s in client.score(request).scores] == [-1.0, -1.25]  # 4 and 5 characters
        llama_server(server, raw_number(value))
        try:
            scores = client.score(request).scores
        except ModelError as err:
            assert "log-probabilit" in str(err) and "\n" not in str(err), str(err)
        else:
            tally.add(CATEGORY, failures=1)
            raise AssertionError(f"{value} accepted as {scores}")
    finally:
        client.close()


def test_a_scoring_reply_with_other_or_odd_token_ids_is_a_model_error(server: Any, tally: Any) -> None:
    tally.add(CATEGORY, tried=3)
    client = get_backend(f"openai:m@{server.url}/v1", **FAST)
    try:
        for ids in ([1.5, 2], [True], [-1]):
            llama_server(server, -0.1, ids)
            with pytest.raises(ModelError, match="token ids"):
                client.score(ScoreRequest("Go to the", (" box",)))
    finally:
        client.close()


def recording(tmp_path: Path, reply: dict[str, Any], backend: str = "openai:m") -> Path:
    request = ScoreRequest("Go to the", (" box", " fire"))
    with RunLog(tmp_path / "rec", {"modality": "text", "backend": backend}) as log:
        log.event("llm_call", step=1, purpose="score", request=request.to_log(), reply=reply)
    return tmp_path / "rec"


@pytest.mark.parametrize(
    "scores",
    [[[40.0, 1], [-1.0, 1]], [[-1.0, -3], [-1.0, 1]], [[-1e308, 2], [-1.0, 1]], [["nan", 1], [-1.0, 1]],
     [[-1.0, 0], [-1.0, 1]], [[-1.0], [-1.0, 1]]],
)  # fmt: skip
def test_a_replay_file_with_unbelievable_scores_is_refused_with_one_line(
    scores: list[Any], tmp_path: Path, tally: Any
) -> None:
    tally.add(CATEGORY, tried=1)
    good = recording(tmp_path / "good", {"text": "", "scores": [[-1.0, 1], [-2.0, 1]], "latency_s": 0.1})
    assert [s.logprob for s in ReplayBackend(str(good)).score(ScoreRequest("Go to the", (" box", " fire"))).scores] == [
        -1.0,
        -2.0,
    ]
    bad = recording(tmp_path / "bad", {"text": "", "scores": scores, "latency_s": 0.1})
    with pytest.raises(BadInputError, match=r"line 2: llm_call reply score 1") as caught:
        ReplayBackend(str(bad))
    assert "\n" not in str(caught.value)


def test_a_replay_file_with_a_negative_token_count_is_refused_by_drive(tmp_path: Path, tally: Any) -> None:
    tally.add(CATEGORY, tried=1)
    bad = recording(tmp_path, {"text": "{}", "prompt_tokens": -4, "completion_tokens": 2, "latency_s": 0.1})
    result = CliRunner().invoke(
        app, ["drive", "--backend", f"replay:{bad}", "--scenario", SMALL_ROOM, "--task-id", "T1", "--sensing", "lidar",
              "--out", str(tmp_path / "run")]
    )  # fmt: skip
    assert result.exit_code == 2 and "prompt_tokens is -4" in result.output, result.output
    assert not (tmp_path / "run" / "run.jsonl").exists()


def test_a_policy_recording_keeps_its_positive_scores(tmp_path: Path) -> None:
    """A heuristic policy's scores (shared words: +2) are not log-probabilities and replay as they were."""
    rec = recording(tmp_path, {"text": "", "scores": [[2.0, 1], [0.0, 1]], "latency_s": 0.0}, "policy:keyword")
    scores = ReplayBackend(str(rec)).score(ScoreRequest("Go to the", (" box", " fire"))).scores
    assert [s.logprob for s in scores] == [2.0, 0.0] and not any(math.isnan(s.logprob) for s in scores)


@pytest.mark.slow
@pytest.mark.reliability
def test_the_fsm_assist_survives_a_list_usage_and_counts_each_failure(tmp_path: Path, server: Any, tally: Any) -> None:
    """`--planner fsm -o assist=llm --realtime` against `"usage": [1, 2]`: the assist thread died on the
    AttributeError and the run was tabled as assisted with 0 suggestions. Now every answer is a counted,
    logged failure (about 140 s: the maze at real time)."""
    tally.add(CATEGORY, tried=1)
    server.default = lambda seen: (
        server.reply(404, {"error": "no /tokenize"}) if seen.path.endswith("/tokenize")
        else server.reply(200, chat_body("openai", "{}", usage=[1, 2]))
    )  # fmt: skip
    out = tmp_path / "run"
    result = CliRunner().invoke(
        app, ["drive", "--planner", "fsm", "-o", "assist=llm", "--realtime", "--backend", f"openai:m@{server.url}/v1",
              "--scenario", "maze_arena", "--task-id", "M1", "--out", str(out), "--quiet"]
    )  # fmt: skip
    crashed = result.exception is not None and not isinstance(result.exception, SystemExit)
    tally.add(CATEGORY, crashes=int(crashed))
    assert not crashed and result.exit_code in (0, 1), result.output
    calls = [json.loads(line) for line in (out / "run.jsonl").read_text().splitlines()]
    errors = [c.get("error") for c in calls if c["type"] == "llm_call"]
    assert errors and all("usage is a list" in (e or "") for e in errors), errors[:3]
    metrics = json.loads((out / "summary.json").read_text())["planner_metrics"]
    assert metrics["suggestions"] == metrics["rejected"]["error"] == len(errors) > 0
