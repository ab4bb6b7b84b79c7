"""The official `openai` SDK against a real `llmnav serve` (the bundled SmolLM2 on 127.0.0.1, with a key).

What SDK code relies on: chat, legacy completions with OpenAI's log-probability lists (streamed too),
the Responses API held to a JSON Schema (streamed too), 404 for a model the server does not serve (its
`--alias` names are served), `models.retrieve`, and error texts that are true of this server.
"""

from __future__ import annotations

import json
import subprocess
from collections.abc import Iterator
from pathlib import Path
from typing import Literal

import openai
import pytest
from pydantic import BaseModel

from tests.backends.conftest import end_serve, start_serve

ALIASES = ("gpt-4o-mini", "acme/robot-1")
PROMPT = "The sky is"


class Sky(BaseModel):
    colour: Literal["blue", "green", "grey"]


@pytest.fixture(scope="module")
def served() -> Iterator[tuple[subprocess.Popen[str], str, str]]:
    """One server for the module (loading the model once), answering to two aliases besides `local`."""
    process, url, key = start_serve(*(arg for name in ALIASES for arg in ("--alias", name)))
    try:
        yield process, url, key
    finally:
        end_serve(process)


@pytest.fixture
def sdk(served: tuple[subprocess.Popen[str], str, str]) -> openai.OpenAI:
    _process, url, key = served
    return openai.OpenAI(base_url=url, api_key=key, max_retries=0)


def test_chat_through_the_sdk_under_every_served_name(sdk: openai.OpenAI) -> None:
    for name in ("local", *ALIASES):
        answer = sdk.chat.completions.create(
            model=name, messages=[{"role": "user", "content": "Say hi."}], max_tokens=4, temperature=0
        )
        assert answer.choices[0].message.content, name
        assert answer.usage is not None and 0 < answer.usage.completion_tokens <= 4


def test_unknown_model_is_404_everywhere(sdk: openai.OpenAI) -> None:
    with pytest.raises(openai.NotFoundError) as chat:
        sdk.chat.completions.create(model="gpt-4o", messages=[{"role": "user", "content": "Hi"}], max_tokens=2)
    assert chat.value.code == "model_not_found" and "`gpt-4o` does not exist" in chat.value.message
    assert all(f"`{name}`" in chat.value.message for name in ("local", *ALIASES))  # says which names work
    with pytest.raises(openai.NotFoundError):
        sdk.completions.create(model="nope", prompt=PROMPT, max_tokens=2)
    with pytest.raises(openai.NotFoundError):
        sdk.responses.create(model="nope", input="Hi", max_output_tokens=16)
    with pytest.raises(openai.NotFoundError):
        sdk.models.retrieve("nope")


def test_models_list_and_retrieve_name_every_alias(sdk: openai.OpenAI) -> None:
    assert [m.id for m in sdk.models.list()] == ["local", *ALIASES]
    for name in ("local", *ALIASES):  # "acme/robot-1" holds a slash, as Hugging Face names do
        model = sdk.models.retrieve(name)
        assert model.id == name and model.object == "model"


def test_legacy_completion_logprobs_in_openais_format(sdk: openai.OpenAI) -> None:
    reply = sdk.completions.create(model="local", prompt=PROMPT, max_tokens=5, logprobs=3, temperature=0)
    choice = reply.choices[0]
    logprobs = choice.logprobs
    assert logprobs is not None and logprobs.tokens and logprobs.token_logprobs is not None
    assert logprobs.top_logprobs is not None and logprobs.text_offset is not None
    n = len(logprobs.tokens)
    assert n == len(logprobs.token_logprobs) == len(logprobs.top_logprobs) == len(logprobs.text_offset) == 5
    assert "".join(logprobs.tokens) == choice.text
    whole = PROMPT + choice.text  # offsets count from the start of the prompt, as OpenAI's do
    for token, offset, chosen, top in zip(
        logprobs.tokens, logprobs.text_offset, logprobs.token_logprobs, logprobs.top_logprobs, strict=True
    ):
        assert whole[offset : offset + len(token)] == token
        assert chosen is not None and chosen <= 0.0
        assert 1 <= len(top) <= 4 and top[token] == pytest.approx(chosen)  # up to N, plus the chosen token
        assert max(top.values()) <= 0.0
    assert logprobs.text_offset[0] == len(PROMPT)


def test_legacy_logprobs_zero_gives_the_chosen_token_only(sdk: openai.OpenAI) -> None:
    reply = sdk.completions.create(model="local", prompt=PROMPT, max_tokens=3, logprobs=0, temperature=0)
    logprobs = reply.choices[0].logprobs
    assert logprobs is not None and logprobs.tokens and logprobs.top_logprobs
    assert [list(top) for top in logprobs.top_logprobs] == [[token] for token in logprobs.tokens]


def test_streamed_legacy_logprobs_carry_the_offset(sdk: openai.OpenAI) -> None:
    stream = sdk.completions.create(model="local", prompt=PROMPT, max_tokens=4, logprobs=2, temperature=0, stream=True)
    tokens: list[str] = []
    offsets: list[int] = []
    text = ""
    for chunk in stream:
        for choice in chunk.choices:
            text += choice.text
            if choice.logprobs is not None and choice.logprobs.tokens:
                tokens += choice.logprobs.tokens
                offsets += choice.logprobs.text_offset or []
    assert len(tokens) == 4 and "".join(tokens) == text
    assert offsets == [len(PROMPT) + len("".join(tokens[:i])) for i in range(len(tokens))]


def test_continuation_scoring_still_reads_llamacpps_fields(
    served: tuple[subprocess.Popen[str], str, str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """llmnav's `openai` backend scores continuations from `logprobs.content`: kept beside OpenAI's lists."""
    from llmnav.backends.openai import OpenAIBackend
    from llmnav.core.chat import ScoreRequest

    _process, url, key = served
    monkeypatch.setenv("OPENAI_API_KEY", key)
    backend = OpenAIBackend(f"local@{url}")
    result = backend.score(ScoreRequest("The fire extinguisher is in the", (" kitchen", " garage")))
    assert len(result.scores) == 2 and all(s.logprob < 0 and s.tokens >= 1 for s in result.scores)


def test_responses_parse_holds_to_the_schema(sdk: openai.OpenAI) -> None:
    parsed = sdk.responses.parse(
        model="local", input="Which colour is the sky?", text_format=Sky, max_output_tokens=40, temperature=0
    )
    assert isinstance(parsed.output_parsed, Sky)
    assert Sky.model_validate_json(parsed.output_text) == parsed.output_parsed


def test_streamed_responses_hold_to_the_schema(sdk: openai.OpenAI) -> None:
    schema = {**Sky.model_json_schema(), "additionalProperties": False}
    stream = sdk.responses.create(
        model="acme/robot-1",
        input="Which colour is the sky?",
        max_output_tokens=40,
        temperature=0,
        stream=True,
        text={"format": {"type": "json_schema", "name": "sky", "schema": schema, "strict": True}},
    )
    text = ""
    kinds: set[str] = set()
    for event in stream:
        kinds.add(event.type)
        if event.type == "response.output_text.delta":
            text += event.delta
    assert "response.completed" in kinds
    assert json.loads(text)["colour"] in ("blue", "green", "grey")


def test_a_format_without_a_schema_is_400(sdk: openai.OpenAI) -> None:
    with pytest.raises(openai.BadRequestError, match="text.format.schema"):
        sdk.responses.create(
            model="local", input="Hi", max_output_tokens=8, text={"format": {"type": "json_schema", "name": "x"}}
        )  # type: ignore[typeddict-item]


def test_embeddings_error_names_no_missing_flag(sdk: openai.OpenAI) -> None:
    with pytest.raises(openai.APIStatusError) as caught:
        sdk.embeddings.create(model="local", input="hello")
    assert caught.value.status_code == 501
    message = caught.value.message
    assert "--embeddings" not in message and "`--" not in message
    assert "does not support embeddings" in message and "llmnav serve" in message


def test_llmnav_run_naming_a_model_the_server_lacks_is_bad_input(
    served: tuple[subprocess.Popen[str], str, str], monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """llmnav's own `openai` backend turns the 404 into one line and exit 2 (a typo in --backend)."""
    from typer.testing import CliRunner

    from llmnav.cli import app

    _process, url, key = served
    monkeypatch.setenv("OPENAI_API_KEY", key)
    args = ["drive", "--planner", "stepwise", "--scenario", "corridor_a", "--task-id", "A1", "--sensing", "lidar"]
    result = CliRunner().invoke(app, [*args, "--backend", f"openai:gpt-4o@{url}", "--out", str(tmp_path / "run")])
    assert result.exit_code == 2, result.output
    assert "does not serve 'gpt-4o'" in result.output and "`local`" in result.output
    assert "Traceback" not in result.output
