"""`llmnav serve` bad input: one line on stderr, exit 2, before any model is loaded."""

from __future__ import annotations

import socket

from typer.testing import CliRunner

from llmnav.cli import app


def test_missing_model_file(tmp_path):
    result = CliRunner().invoke(app, ["serve", "--model", str(tmp_path / "absent.gguf"), "--port", "0"])
    assert result.exit_code == 2
    assert result.stderr.strip().count("\n") == 0 and "local model file not found" in result.stderr
    assert result.stdout == ""


def test_not_a_gguf_file(tmp_path):
    fake = tmp_path / "model.gguf"
    fake.write_bytes(b"not a model")
    result = CliRunner().invoke(app, ["serve", "--model", str(fake), "--port", "0"])
    assert result.exit_code == 2 and "not a GGUF model" in result.stderr


def test_port_in_use_before_loading():
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        result = CliRunner().invoke(app, ["serve", "--port", str(port)])
    assert result.exit_code == 2
    assert result.stderr.strip() == f"error: port {port} on 127.0.0.1 is already in use: choose another with --port"


def test_blank_or_padded_alias_is_refused_before_loading():
    for name in ("", "  ", " gpt-4o"):
        result = CliRunner().invoke(app, ["serve", "--alias", name, "--port", "0"])
        assert result.exit_code == 2 and result.stdout == "", (name, result.output)
        assert result.stderr.strip().count("\n") == 0 and f"--alias {name!r}: give a model name" in result.stderr
