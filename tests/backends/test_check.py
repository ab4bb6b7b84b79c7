"""`llmnav backends --check SPEC`: probes exactly that spec's server (a scripted loopback server here)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from llmnav.backends.http import forget_text_only
from llmnav.cli import app

REJECTION = {"error": {"code": 500, "message": "image input is not supported - hint: mmproj", "type": "server_error"}}


@pytest.fixture(autouse=True)
def _env(monkeypatch):
    monkeypatch.delenv("OPENAI_API_KEY", raising=False)
    monkeypatch.delenv("OLLAMA_API_KEY", raising=False)
    monkeypatch.setenv("COLUMNS", "200")
    forget_text_only()


def _openai_like(server, *, images: bool, answer: str):
    """A server in the manner of llama.cpp's: lists `local`, rejects images unless `images`, answers `answer`."""

    def reply(seen):
        if seen.method == "GET" and seen.path == "/v1/models":
            return server.reply(200, {"object": "list", "data": [{"id": "local", "aliases": ["smol"]}]})
        if seen.path == "/tokenize":  # no scoring here: a /tokenize that crashed would be a server failure
            return server.reply(404, {"error": {"message": "File Not Found"}})
        has_image = any(isinstance(m["content"], list) for m in seen.body["messages"])
        if has_image and not images:
            return server.reply(500, REJECTION)
        return server.reply(200, {"choices": [{"message": {"role": "assistant", "content": answer}}]})

    server.default = reply


def _lines(output: str) -> dict[str, str]:
    return {line.split(":")[0][4:].strip(): line for line in output.splitlines() if line[:2] in ("ok", "no")}


def test_text_only_server(server):
    _openai_like(server, images=False, answer='{"colour": "blue"}')
    result = CliRunner().invoke(app, ["backends", "--check", f"openai:local@{server.url}/v1"])
    lines = _lines(result.output)
    assert result.exit_code == 1, result.output
    assert lines["reachable"].startswith("ok") and lines["models listed"].startswith("ok")
    assert lines["model present"].startswith("ok")
    assert lines["accepts images"].startswith("no") and "--sensing lidar" in lines["accepts images"]
    assert lines["accepts a JSON Schema"].startswith("ok")
    schema_request = [s for s in server.seen if s.method == "POST" and "response_format" in s.body][-1]
    assert schema_request.body["response_format"]["type"] == "json_schema"


def test_everything_ok_and_absent_model(server):
    _openai_like(server, images=True, answer='{"colour": "blue"}')
    ok = CliRunner().invoke(app, ["backends", "--check", f"openai:smol@{server.url}/v1"])
    assert ok.exit_code == 0, ok.output
    assert all(line.startswith("ok") for line in _lines(ok.output).values()) and len(_lines(ok.output)) == 5
    absent = CliRunner().invoke(app, ["backends", "--check", f"openai:gpt-9@{server.url}/v1"])
    assert absent.exit_code == 1
    assert _lines(absent.output)["model present"].startswith("no")


def test_answer_that_ignores_the_schema_is_reported(server):
    _openai_like(server, images=True, answer="the sky is blue")
    result = CliRunner().invoke(app, ["backends", "--check", f"openai:local@{server.url}/v1"])
    assert result.exit_code == 1
    assert _lines(result.output)["accepts a JSON Schema"].startswith("no")


def test_ollama_check(server):
    def reply(seen):
        if seen.path == "/api/tags":
            return server.reply(200, {"models": [{"name": "llama3.2-vision:latest"}]})
        if any("images" in m for m in seen.body["messages"]):
            return server.reply(500, {"error": "this model is missing data required for image input"})
        return server.reply(200, {"message": {"role": "assistant", "content": json.dumps({"colour": "blue"})}})

    server.default = reply
    # OLLAMA_HOST is read when the check builds its backend
    result = CliRunner().invoke(app, ["backends", "--check", "ollama:llama3.2-vision"], env={"OLLAMA_HOST": server.url})
    lines = _lines(result.output)
    assert lines["model present"].startswith("ok") and lines["accepts images"].startswith("no"), result.output


def test_unreachable(closed_port_url):
    result = CliRunner().invoke(app, ["backends", "--check", f"openai:local@{closed_port_url}/v1"])
    assert result.exit_code == 1
    assert _lines(result.output)["reachable"].startswith("no")


def test_unknown_spec_is_one_line_exit_2():
    done = subprocess.run(
        [str(Path(sys.executable).parent / "llmnav"), "backends", "--check", "nosuch:thing"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 2
    assert done.stderr.strip().count("\n") == 0 and "unknown backend 'nosuch'" in done.stderr
    assert done.stdout == ""


HOSTILE_NAMES = ["\x1b]0;pwned\x07title", "\x1b[2Jclear", "bell\x07"]


def test_model_names_from_a_server_reach_the_terminal_sanitised(server):
    def reply(seen):
        if seen.path == "/v1/models":
            return server.reply(200, {"object": "list", "data": [{"id": name} for name in HOSTILE_NAMES]})
        if seen.path == "/api/tags":
            return server.reply(200, {"models": [{"name": name} for name in HOSTILE_NAMES]})
        return server.reply(200, {"choices": [{"message": {"role": "assistant", "content": "{}"}}]})

    server.default = reply
    for spec, env in ((f"openai:x@{server.url}/v1", {}), ("ollama:x", {"OLLAMA_HOST": server.url})):
        result = CliRunner().invoke(app, ["backends", "--check", spec], env=env)
        assert "\x1b" not in result.output and "\x07" not in result.output, repr(result.output)
        assert "\\x1b]0;pwned" in result.output  # shown, as a visible escape
