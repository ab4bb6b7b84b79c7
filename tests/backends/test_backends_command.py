"""`llmnav backends`: every registered backend with its readiness; a broken one does not hide the rest."""

from __future__ import annotations

import importlib.metadata

import pytest
from typer.testing import CliRunner

from llmnav.cli import app
from llmnav.commands import backends as command


@pytest.fixture
def quiet_env(monkeypatch, closed_port_url):
    monkeypatch.setenv("OLLAMA_HOST", closed_port_url)  # refused at once instead of probing a real server
    monkeypatch.setenv("OPENAI_BASE_URL", closed_port_url + "/v1")
    monkeypatch.delenv("OPENAI_API_KEY", raising=False)
    monkeypatch.delenv("GEMINI_API_KEY", raising=False)
    monkeypatch.delenv("GOOGLE_API_KEY", raising=False)
    monkeypatch.setenv("COLUMNS", "200")


def test_lists_every_registered_backend(quiet_env, monkeypatch):
    monkeypatch.setenv("GEMINI_API_KEY", "AIza-fake-for-listing")
    result = CliRunner().invoke(app, ["backends"])
    assert result.exit_code == 0, result.output
    rows = {line.split("│")[1].strip(): line for line in result.output.splitlines() if line.count("│") >= 5}
    for name in ("ollama", "gemini", "openai", "replay", "local"):  # local: ready, not ready or broken
        assert name in rows, result.output
    assert "yes" in rows["gemini"] and "GEMINI_API_KEY" in rows["gemini"]
    assert "no" in rows["ollama"] and "no server" in rows["ollama"]
    assert "no" in rows["openai"] and "not usable" in rows["openai"]
    assert "replay:" in rows["replay"]
    assert "AIza-fake-for-listing" not in result.output


def test_broken_backend_is_shown_not_raised(quiet_env, monkeypatch):
    real = importlib.metadata.entry_points

    def with_a_broken_one(group: str):
        eps = list(real(group=group))
        eps.append(importlib.metadata.EntryPoint("ghost", "llmnav_no_such_module:Ghost", group))
        return eps

    monkeypatch.setattr(importlib.metadata, "entry_points", with_a_broken_one)
    rows = {row.name: row for row in command.collect_rows()}
    assert rows["ghost"].ready is None
    assert "ModuleNotFoundError" in rows["ghost"].detail and "\n" not in rows["ghost"].detail
    assert rows["replay"].ready is True  # the others are still listed
    result = CliRunner().invoke(app, ["backends"])
    assert result.exit_code == 0 and "broken" in result.output and "ghost" in result.output


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--check", "policy:first", "--sensing", "sonar"], "--sensing 'sonar': a comma list of lidar, image"),
        (["--check", "policy:first", "--sensing", "lidar,lidar"], "lists lidar more than once"),
        (["--sensing", "lidar"], "--sensing goes with --check SPEC"),
    ],
)
def test_bad_sensing_is_one_line_exit_2(quiet_env, args, message):
    result = CliRunner().invoke(app, ["backends", *args])
    assert result.exit_code == 2, result.output
    assert result.stderr.strip().count("\n") == 0 and message in result.stderr
