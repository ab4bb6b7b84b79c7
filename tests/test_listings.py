"""The listing commands in shell scripts: `backends`, `planners` and `scenarios` take `--format table|tsv|json`.

JSON and TSV put only data on stdout; a table written to a pipe is never cut at 80 columns (its full width,
one line per row, no ellipses), so `llmnav backends | grep oracle` finds `policy:oracle`. An unknown
format is one line on stderr and exit 2.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from llmnav.cli import app

LLMNAV = str(Path(sys.executable).parent / "llmnav")
LISTINGS = (["backends"], ["planners"], ["scenarios"], ["scenarios", "list"], ["planners", "fsm"])


@pytest.fixture(autouse=True)
def quiet_env(monkeypatch: pytest.MonkeyPatch, closed_port_url: str) -> None:
    """No server is probed (refused at once), no key is set, and the terminal is narrow."""
    monkeypatch.setenv("OLLAMA_HOST", closed_port_url)
    monkeypatch.setenv("OPENAI_BASE_URL", closed_port_url + "/v1")
    for name in ("OPENAI_API_KEY", "GEMINI_API_KEY", "GOOGLE_API_KEY"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("COLUMNS", "80")


def test_backends_piped_to_grep_finds_the_oracle_policy() -> None:
    """The issue's own command, through a real shell pipe (stdout is not a terminal)."""
    script = f"{LLMNAV} backends | grep oracle"
    result = subprocess.run(["bash", "-c", script], capture_output=True, text=True, timeout=120, env=os.environ)
    assert result.returncode == 0, result.stderr
    assert "policy:oracle" in result.stdout and "…" not in result.stdout


@pytest.mark.parametrize("args", LISTINGS, ids=" ".join)
def test_piped_tables_are_never_cut(args: list[str]) -> None:
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    assert "…" not in result.stdout
    widths = [len(line) for line in result.stdout.splitlines() if line.startswith(("│", "┃"))]
    assert widths and max(widths) > 80  # wider than the terminal says: nothing squeezed to fit


def test_piped_scenario_table_keeps_every_description_on_its_row() -> None:
    from llmnav.world.scenario import list_scenarios, load_scenario

    lines = CliRunner().invoke(app, ["scenarios"]).stdout.splitlines()
    for name in list_scenarios():
        row = next(line for line in lines if line.startswith(f"│ {name} "))
        assert load_scenario(name).description in row  # whole, on the row's one line


@pytest.mark.parametrize("args", LISTINGS, ids=" ".join)
def test_json_is_only_data(args: list[str]) -> None:
    result = CliRunner().invoke(app, [*args, "--format", "json"])
    assert result.exit_code == 0, result.output
    data = json.loads(result.stdout)  # nothing else on stdout
    assert data


@pytest.mark.parametrize("args", LISTINGS, ids=" ".join)
def test_tsv_is_a_header_and_one_line_per_record(args: list[str]) -> None:
    result = CliRunner().invoke(app, [*args, "--format", "tsv"])
    assert result.exit_code == 0, result.output
    header, *rows = result.stdout.rstrip("\n").split("\n")
    assert rows and "│" not in result.stdout and "\x1b" not in result.stdout
    assert all(row.count("\t") == header.count("\t") for row in rows)


def test_listing_records_match_what_is_registered() -> None:
    from llmnav.planners.base import usable_planner_names
    from llmnav.world.scenario import list_scenarios

    backends = json.loads(CliRunner().invoke(app, ["backends", "--format", "json"]).stdout)
    policy = [b for b in backends if b["name"] == "policy"]
    assert policy and policy[0]["ready"] is True and policy[0]["broken"] is False
    assert "policy:oracle" in policy[0]["description"]
    assert {"name", "ready", "spec_example", "detail", "description"} <= set(backends[0])
    planners = CliRunner().invoke(app, ["planners", "--format", "tsv"]).stdout.splitlines()
    assert [line.split("\t")[0] for line in planners[1:]] == list(usable_planner_names())
    scenarios = json.loads(CliRunner().invoke(app, ["scenarios", "--format", "json"]).stdout)
    assert [s["name"] for s in scenarios] == list(list_scenarios())
    assert all(s["width_m"] > 0 and s["depth_m"] > 0 and s["tasks"] >= 1 for s in scenarios)


def test_backend_check_as_data() -> None:
    result = CliRunner().invoke(app, ["backends", "--check", "policy:oracle", "--format", "json"])
    assert result.exit_code == 0, result.output
    checks = json.loads(result.stdout)
    assert checks and all(set(c) == {"check", "ok", "detail"} for c in checks)


@pytest.mark.parametrize("args", [*LISTINGS, ["backends", "--check", "policy:oracle"]], ids=" ".join)
def test_unknown_format_is_one_line_and_exit_2(args: list[str]) -> None:
    result = CliRunner().invoke(app, [*args, "--format", "yaml"])
    assert result.exit_code == 2
    assert result.stdout == ""
    assert result.stderr.strip() == "error: --format 'yaml': expected table, tsv or json"


def test_format_before_a_scenarios_subcommand_is_refused() -> None:
    result = CliRunner().invoke(app, ["scenarios", "--format", "json", "show", "factory"])
    assert result.exit_code == 2 and result.stdout == ""
    assert result.stderr.count("\n") == 1 and "scenarios show --format" in result.stderr
