"""`llmnav serve` stops within 2 s on SIGINT or SIGTERM, even mid-stream, and answers `models.retrieve`.

Each test starts its own `llmnav serve --port 0` (the bundled SmolLM2 on 127.0.0.1) as a subprocess
(the `serve_process` fixture).
"""

from __future__ import annotations

import json
import signal
import subprocess
import threading
import time

import httpx
import openai
import pytest

STOP_WITHIN_S = 2.0
LONG = {  # an answer that cannot end early: llama.cpp's `ignore_eos` generates all 3000 tokens
    "model": "local",
    "max_tokens": 3000,
    "ignore_eos": True,
    "messages": [{"role": "user", "content": "Write a very long story about a robot in a factory."}],
}


def _auth(key: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {key}"}


def _stop_and_time(process: subprocess.Popen[str], sig: signal.Signals) -> float:
    started = time.monotonic()
    process.send_signal(sig)
    try:
        process.wait(timeout=60)
    except subprocess.TimeoutExpired:
        process.kill()
        raise
    return time.monotonic() - started


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_stops_within_two_seconds_mid_stream_and_ends_the_stream_cleanly(serve_process, sig) -> None:
    process, url, key = serve_process
    lines: list[str] = []
    outcome: list[str] = []
    first_token = threading.Event()

    def stream() -> None:
        try:
            with httpx.stream(
                "POST", f"{url}/chat/completions", json={**LONG, "stream": True}, headers=_auth(key), timeout=120
            ) as reply:
                for line in reply.iter_lines():
                    lines.append(line)
                    first_token.set()
            outcome.append("complete")
        except httpx.HTTPError as err:
            outcome.append(f"{type(err).__name__}: {err}")
        first_token.set()

    client = threading.Thread(target=stream)
    client.start()
    assert first_token.wait(120), "no token streamed"
    time.sleep(0.5)  # well inside a 3000-token answer
    took = _stop_and_time(process, sig)
    client.join(10)
    assert not client.is_alive(), "the client's stream was kept open"
    assert took < STOP_WITHIN_S, f"{sig.name}: stopped after {took:.2f} s"
    assert process.returncode == 0
    assert process.stderr is not None and process.stderr.read().strip().splitlines()[-1] == "server stopped"
    # the response was ended properly (no truncated chunk), its last event saying why
    assert outcome == ["complete"], outcome
    events = [json.loads(line[6:]) for line in lines if line.startswith("data: {")]
    assert any(e.get("choices") for e in events), "no token before the stop"
    assert events[-1] == {"error": {"message": "the server is stopping", "type": "server_stopping"}}


def test_an_unstreamed_request_in_flight_gets_503(serve_process) -> None:
    process, url, key = serve_process
    replies: list[httpx.Response] = []
    client = threading.Thread(
        target=lambda: replies.append(httpx.post(f"{url}/chat/completions", json=LONG, headers=_auth(key), timeout=120))
    )
    client.start()
    time.sleep(2.0)  # the request is being generated
    took = _stop_and_time(process, signal.SIGINT)
    client.join(10)
    assert took < STOP_WITHIN_S and replies, took
    assert replies[0].status_code == 503
    assert replies[0].json()["error"]["message"] == "the server is stopping"


def test_models_retrieve_through_the_openai_sdk(serve_process) -> None:
    process, url, key = serve_process
    sdk = openai.OpenAI(base_url=url, api_key=key, max_retries=0)
    model = sdk.models.retrieve("local")
    assert model.id == "local" and model.object == "model"
    assert [m.id for m in sdk.models.list()] == ["local"]
    with pytest.raises(openai.NotFoundError, match="does not exist"):
        sdk.models.retrieve("gpt-4")
    with pytest.raises(openai.AuthenticationError):
        openai.OpenAI(base_url=url, api_key="wrong", max_retries=0).models.retrieve("local")
    # and a chat still goes through the relay
    answer = sdk.chat.completions.create(model="local", messages=[{"role": "user", "content": "Hi"}], max_tokens=4)
    assert answer.choices[0].message.content is not None
    assert _stop_and_time(process, signal.SIGTERM) < STOP_WITHIN_S
