"""Secrets: with recognisable fake API keys set, drive episodes against loopback servers that work, fail,
and even echo the key back in their error messages; no key may appear in any run file (log, summary,
images, plot), in the CLI's output, in a backend's error or exception chain, or in log records.
"""

from __future__ import annotations

import base64
import json
import logging
import traceback
from pathlib import Path
from typing import Any
from urllib.parse import quote

import pytest
from typer.testing import CliRunner

import llmnav.runs.runner as runner
from llmnav.backends.base import ChatRequest, Message, get_backend
from llmnav.cli import app
from llmnav.errors import LlmnavError

CATEGORY = "secrets"
SMALL_ROOM = str(Path(__file__).parents[1] / "runner" / "small_room.yaml")
KEYS = {
    "OPENAI_API_KEY": "sk-FAKEopenai-Zq8VtY3kLm0Rw2Xc",
    "GEMINI_API_KEY": "AIzaFAKEgemini-Pf7Hs4Jd9Kq1Nb",
}
FAST = {"max_retries": 1, "backoff_base_s": 0.01, "backoff_max_s": 0.02, "timeout_s": 0.5,
        "connect_timeout_s": 0.5}
COMPLETE = '```json\n{"goal": "g", "reasoning": "r", "scene_description": "s", ' \
    '"action": {"command": "COMPLETE", "parameters": 0}}\n```'


def fragments() -> list[str]:
    """The keys and distinctive pieces of them (a partial leak counts too)."""
    return [piece for key in KEYS.values() for piece in (key, key[-12:], key[:14])]


def leaks(text: str | bytes) -> list[str]:
    data = text if isinstance(text, bytes) else text.encode("utf-8", errors="replace")
    return [f for f in fragments() if f.encode() in data]


def good_body(backend: str, text: str = COMPLETE) -> dict[str, Any]:
    if backend == "openai":
        return {"choices": [{"message": {"role": "assistant", "content": text}, "finish_reason": "stop"}]}
    if backend == "gemini":
        return {"candidates": [{"content": {"role": "model", "parts": [{"text": text}]}}]}
    return {"message": {"role": "assistant", "content": text}, "done": True}


def echo(Fault: Any, status: int, html: bool = False) -> Any:
    """A server error that quotes the credentials it received (some real APIs do)."""

    def reply(seen: Any) -> Any:
        quoted = f"{seen.headers.get('authorization', '')} {seen.headers.get('x-goog-api-key', '')}"
        if html:
            return Fault("raw", status, f"<html><body>key {quoted} rejected</body></html>", "text/html")
        return Fault("ok", status, {"error": {"message": f"API key not valid: {quoted}", "status": "DENIED"}})

    return reply


FULL = [pytest.mark.slow, pytest.mark.reliability]
SCENARIOS = ["works", "echo 400", "echo 500 retried", "echo HTML 502", "reset"]


def configure(backend: str, url: str, monkeypatch: pytest.MonkeyPatch) -> str:
    for name, value in KEYS.items():
        monkeypatch.setenv(name, value)
    if backend == "openai":
        return f"openai:m@{url}/v1"
    if backend == "gemini":
        monkeypatch.setenv("LLMNAV_GEMINI_BASE_URL", url)
        return "gemini:gemini-2.0-flash"
    monkeypatch.setenv("OLLAMA_HOST", url)
    return "ollama:llama3.1"


def scripted(fault_kit: Any, backend: str, scenario: str) -> Any:
    Fault = fault_kit["Fault"]
    return {
        "works": Fault("ok", 200, good_body(backend)),
        "echo 400": echo(Fault, 400),
        "echo 500 retried": echo(Fault, 500),
        "echo HTML 502": echo(Fault, 502, html=True),
        "reset": Fault("reset"),
    }[scenario]


@pytest.mark.parametrize(
    "backend",
    ["openai", pytest.param("gemini", marks=FULL), pytest.param("ollama", marks=FULL)],
)
def test_no_key_in_runs_output_or_errors(
    backend: str, tmp_path: Path, fault_server: Any, fault_kit: Any, monkeypatch: Any, tally: Any,
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.DEBUG)
    real = runner.get_backend
    monkeypatch.setattr(runner, "get_backend", lambda spec, **o: real(spec, **{**FAST, **o}))
    spec = configure(backend, fault_server.url, monkeypatch)
    found: dict[str, list[str]] = {}
    for scenario in SCENARIOS:
        fault_server.default = scripted(fault_kit, backend, scenario)
        out = tmp_path / scenario.replace(" ", "_")
        result = CliRunner().invoke(
            app, ["drive", "--planner", "stepwise", "--backend", spec, "--scenario", SMALL_ROOM,
                  "--task-id", "T1", "--sensing", "lidar,image", "--out", str(out), "--json"]
        )
        assert result.exit_code in (0, 1, 4), result.output  # 4: the server failed
        texts = {"cli output": result.output}
        if result.exception is not None and not isinstance(result.exception, SystemExit):
            texts["exception"] = "".join(traceback.format_exception(result.exception))
        for file in out.rglob("*"):
            if file.is_file():
                texts[str(file.relative_to(tmp_path))] = file.read_bytes()  # type: ignore[assignment]
        # the same failure straight from the backend: message, repr and the whole exception chain
        client = real(spec, **FAST)
        try:
            client.chat(ChatRequest(messages=(Message("user", "hello"),)))
        except LlmnavError as err:
            texts["error"] = str(err) + repr(err) + "".join(traceback.format_exception(err))
        finally:
            client.close()
        texts["repr"] = repr(client) + repr(getattr(client, "client", ""))
        for where, text in texts.items():
            hit = leaks(text)
            if hit:
                found.setdefault(scenario, []).append(f"{where}: {hit}")
        tally.add(CATEGORY, tried=1, leaked=int(scenario in found))
        tally.note_add(CATEGORY, "servers", scenario)
    log_text = "\n".join(r.getMessage() for r in caplog.records)
    if leaks(log_text):
        found["log records"] = leaks(log_text)
        tally.add(CATEGORY, leaked=1)
    # the echo servers did receive the keys: the test would see a leak if redaction failed
    received = " ".join(str(s.headers) for s in fault_server.seen)
    if backend != "ollama":
        assert leaks(received), "the server never saw a key; the test proves nothing"
    assert not found, found


def test_backends_command_shows_no_key(fault_server: Any, fault_kit: Any, monkeypatch: Any, tally: Any) -> None:
    fault_server.default = echo(fault_kit["Fault"], 401)
    configure("gemini", fault_server.url, monkeypatch)
    monkeypatch.setenv("OPENAI_BASE_URL", f"{fault_server.url}/v1")
    monkeypatch.setenv("OLLAMA_HOST", fault_server.url)
    result = CliRunner().invoke(app, ["backends"])
    tally.add(CATEGORY, tried=1, leaked=int(bool(leaks(result.output))))
    assert not leaks(result.output), result.output
    # and a backend object never shows its key
    backend = get_backend("gemini")
    assert not leaks(repr(backend) + backend.spec)


PASSWORD = "pw-FAKEuserinfo-Hq4Zr8"


def test_url_credentials_and_an_echoed_key_are_never_logged_or_shown(
    tmp_path: Path, fault_server: Any, fault_kit: Any, monkeypatch: Any, tally: Any
) -> None:
    """`openai:m@http://user:PASS@host/v1`, and a model that quotes the key and the password in its answer."""
    tally.add(CATEGORY, tried=3)
    monkeypatch.setenv("OPENAI_API_KEY", KEYS["OPENAI_API_KEY"])
    quoting = COMPLETE.replace('"reasoning": "r"', f'"reasoning": "your key is {KEYS["OPENAI_API_KEY"]}, {PASSWORD}"')
    fault_server.default = fault_kit["Fault"]("ok", 200, good_body("openai", quoting))
    host = fault_server.url.removeprefix("http://")
    spec = f"openai:m@http://alice:{PASSWORD}@{host}/v1"
    out = tmp_path / "run"
    result = CliRunner().invoke(
        app, ["drive", "--planner", "stepwise", "--backend", spec, "--scenario", SMALL_ROOM, "--task-id", "T1",
              "--sensing", "lidar", "--out", str(out), "--json", "--view"]
    )  # fmt: skip
    assert result.exit_code in (0, 1), result.output
    assert any("authorization" in s.headers for s in fault_server.seen)  # the credentials did go out
    texts: dict[str, bytes] = {"cli output": result.output.encode()}
    texts.update({str(f.relative_to(tmp_path)): f.read_bytes() for f in out.rglob("*") if f.is_file()})
    assert {"run/run.jsonl", "run/summary.json", "run/view.html"} <= set(texts)
    check = CliRunner().invoke(app, ["backends", "--check", spec])
    texts["--check"] = check.output.encode()
    found = {where: hit for where, text in texts.items() if (hit := [w for w in (PASSWORD, "alice:", *fragments())
                                                                     if w.encode() in text])}  # fmt: skip
    tally.add(CATEGORY, leaked=len(found))
    assert not found, found
    assert b"***" in texts["run/run.jsonl"]  # redacted, not dropped


def test_an_empty_url_after_the_at_sign_is_bad_input(fault_server: Any, monkeypatch: Any, tally: Any) -> None:
    tally.add(CATEGORY, tried=1)
    monkeypatch.setenv("OPENAI_API_KEY", KEYS["OPENAI_API_KEY"])
    monkeypatch.delenv("OPENAI_BASE_URL", raising=False)
    drive = ["drive", "--backend", "openai:m@", "--task-id", "T1", "--scenario", SMALL_ROOM, "--sensing", "lidar"]
    for command in (["backends", "--check", "openai:m@"], drive):
        result = CliRunner().invoke(app, command)
        assert result.exit_code in (1, 2) and "no server URL after '@'" in result.output, result.output


@pytest.mark.parametrize("view", ["live table", "--quiet"])
def test_the_terminal_view_shows_no_echoed_key(
    view: str, tmp_path: Path, fault_server: Any, fault_kit: Any, monkeypatch: Any, tally: Any
) -> None:
    """The table drawn during a drive (not `--json`) shows the model's reasoning: keys in it are redacted."""
    tally.add(CATEGORY, tried=1)
    monkeypatch.setenv("OPENAI_API_KEY", KEYS["OPENAI_API_KEY"])
    quoting = COMPLETE.replace('"reasoning": "r"', f'"reasoning": "key {KEYS["OPENAI_API_KEY"]} {PASSWORD}"')
    fault_server.default = fault_kit["Fault"]("ok", 200, good_body("openai", quoting))
    spec = f"openai:m@http://alice:{PASSWORD}@{fault_server.url.removeprefix('http://')}/v1"
    flags = ["--quiet"] if view == "--quiet" else []
    result = CliRunner().invoke(
        app, ["drive", "--planner", "stepwise", "--backend", spec, "--scenario", SMALL_ROOM, "--task-id", "T1",
              "--sensing", "lidar", "--out", str(tmp_path / "run"), *flags]
    )  # fmt: skip
    assert result.exit_code in (0, 1), result.output
    assert "reasoning" in result.output or view == "--quiet"  # the table, with its reasoning column, was drawn
    hit = [w for w in (PASSWORD, *fragments()) if w in result.output]
    tally.add(CATEGORY, leaked=int(bool(hit)))
    assert not hit, result.output


def derived_forms(user: str, password: str, key: str) -> dict[str, str]:
    """What llmnav sends for these credentials, each form written out by hand (the test's own oracle)."""
    return {
        "key": key,
        "bearer": f"Bearer {key}",
        "password": password,
        "basic": base64.b64encode(f"{user}:{password}".encode()).decode(),
        "key url-encoded": quote(key, safe=""),
        "password url-encoded": quote(password, safe=""),
    }


def test_derived_forms_of_a_secret_are_never_shown_or_logged(
    tmp_path: Path, fault_server: Any, fault_kit: Any, monkeypatch: Any, tally: Any
) -> None:
    """A server that echoes the Authorization header it got (Bearer key, Basic base64 of URL credentials) and
    the key URL-encoded, in its model list and in the model's answer: `--check`, run.jsonl and view.html
    show none of them."""
    key = "sk-KEY/VALUE+123=abc"  # characters that change under URL encoding
    user, password = "alice", "PASSW0RDX/+=z"
    forms = derived_forms(user, password, key)
    monkeypatch.setenv("OPENAI_API_KEY", key)
    monkeypatch.delenv("OPENAI_BASE_URL", raising=False)

    def echoing(seen: Any) -> Any:
        """Echo the Authorization header, and its credential URL-encoded (Basic: the password decoded)."""
        sent = seen.headers.get("authorization", "")
        scheme, _, credential = sent.partition(" ")
        if scheme == "Basic":
            credential = base64.b64decode(credential).decode().partition(":")[2]
        said = f"{sent} | {quote(credential, safe='')}"
        if seen.path.endswith("/models"):
            return fault_kit["Fault"]("ok", 200, {"data": [{"id": "m"}, {"id": f"hostile, key={said}"}]})
        text = COMPLETE.replace('"reasoning": "r"', f'"reasoning": {json.dumps(said)}')
        return fault_kit["Fault"]("ok", 200, good_body("openai", text))

    fault_server.default = echoing
    host = fault_server.url.removeprefix("http://")
    texts: dict[str, bytes] = {}
    for who, spec in (("bearer", f"openai:m@{fault_server.url}/v1"),
                      ("basic", f"openai:m@http://{user}:{quote(password, safe='')}@{host}/v1")):  # fmt: skip
        check = CliRunner().invoke(app, ["backends", "--check", spec])
        texts[f"{who} --check"] = check.output.encode()
        out = tmp_path / who
        result = CliRunner().invoke(
            app, ["drive", "--planner", "stepwise", "--backend", spec, "--scenario", SMALL_ROOM, "--task-id", "T1",
                  "--sensing", "lidar", "--out", str(out), "--json", "--view"]
        )  # fmt: skip
        assert result.exit_code in (0, 1), result.output
        texts[f"{who} drive output"] = result.output.encode()
        texts.update({f"{who} {f.name}": f.read_bytes() for f in out.rglob("*") if f.is_file()})
    seen = " ".join(s.headers.get("authorization", "") for s in fault_server.seen)
    assert forms["bearer"] in seen and f"Basic {forms['basic']}" in seen  # both forms did go out
    assert {"bearer run.jsonl", "basic run.jsonl", "basic view.html"} <= set(texts)
    found = {where: hits for where, text in texts.items()
             if (hits := [name for name, form in forms.items() if form.encode() in text])}  # fmt: skip
    tally.add(CATEGORY, tried=len(texts), leaked=len(found))
    assert not found, found
    assert b"***" in texts["basic run.jsonl"] and b"***" in texts["bearer --check"]
