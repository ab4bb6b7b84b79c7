"""Cost and cache through the CLI: a sweep's second pass through `--cache` sends nothing, prices, `--max-cost`.

The episodes are the hybrid planner deciding through llmnav's `openai` backend against the loopback
`server` (tests/conftest.py), which counts the requests that reach it and reports 1000 prompt and 50
completion tokens per answer. A price file makes that model paid: 1000 USD per million prompt tokens, so
each call costs exactly 1 USD.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from llmnav.cli import app

SMALL_ROOM = Path(__file__).parents[1] / "runner" / "small_room.yaml"
ANSWER = {"option": 1, "reasoning": "the first option"}
PROMPT_TOKENS, COMPLETION_TOKENS = 1000, 50
PRICES = 'as_of = 2026-01-01\n[openai]\n"m" = { prompt = 1000.0, completion = 0.0 }\n'


@pytest.fixture
def chat_server(server: Any) -> Any:
    body = {
        "choices": [{"message": {"role": "assistant", "content": json.dumps(ANSWER)}, "finish_reason": "stop"}],
        "model": "m",
        "usage": {"prompt_tokens": PROMPT_TOKENS, "completion_tokens": COMPLETION_TOKENS},
    }
    server.default = server.reply(200, body)
    return server


def _grid(tmp_path: Path, url: str, trials: int = 1) -> Path:
    scenario = tmp_path / "small_room.yaml"
    shutil.copy(SMALL_ROOM, scenario)
    grid = tmp_path / "grid.yaml"
    grid.write_text(
        f"scenario: {scenario}\ntasks: [T1]\nposes: [1, 2]\ntrials: {trials}\nplanner: [hybrid]\n"
        f"backend: ['openai:m@{url}/v1']\nsensing: [lidar]\ndecide: [generate]\noptions: {{max_iterations: 1}}\n"
    )
    return grid


def _ablate(grid: Path, out: Path, *args: str) -> Any:
    return CliRunner().invoke(app, ["ablate", "--grid", str(grid), "--out", str(out), *args])


def _summaries(folder: Path) -> list[dict[str, Any]]:
    return [json.loads(p.read_text()) for p in sorted(folder.glob("*/summary.json"))]


def _calls(folder: Path) -> list[dict[str, Any]]:
    events = [json.loads(line) for p in sorted(folder.glob("*/run.jsonl")) for line in p.read_text().splitlines()]
    return [e for e in events if e.get("type") == "llm_call"]


def test_a_second_sweep_through_the_cache_sends_no_request(chat_server, tmp_path):
    grid, cache = _grid(tmp_path, chat_server.url), tmp_path / "cache"
    first = _ablate(grid, tmp_path / "first", "--cache", str(cache))
    assert first.exit_code == 0, first.output
    sent = len(chat_server.seen)
    assert sent == len(_calls(tmp_path / "first")) > 0
    assert {c["cache"] for c in _calls(tmp_path / "first")} == {"miss"}

    second = _ablate(grid, tmp_path / "second", "--cache", str(cache))  # the same grid, a new folder
    assert second.exit_code == 0, second.output
    assert len(chat_server.seen) == sent  # not one request more
    calls = _calls(tmp_path / "second")
    assert len(calls) == sent and {c["cache"] for c in calls} == {"hit"}
    firsts, seconds = _summaries(tmp_path / "first"), _summaries(tmp_path / "second")
    assert [s["final_pose"] for s in seconds] == [s["final_pose"] for s in firsts]  # the same answers, the same runs
    assert [s["cache_hits"] for s in seconds] == [s["llm_calls"] for s in seconds]

    # score labels the cached runs in every table and counts their hits in the cost table
    scored = CliRunner().invoke(app, ["score", str(tmp_path / "first"), str(tmp_path / "second"), "--format", "json"])
    assert scored.exit_code == 0, scored.output
    tables = {t["name"]: t for t in json.loads(scored.stdout)}
    for name in ("episodes", "cost"):
        labels = [r["condition"] for r in tables[name]["records"]]
        assert "all (from cache)" in labels and "all" in labels, (name, labels)
    cost = {r["condition"]: r for r in tables["cost"]["records"]}
    assert cost["all (from cache)"]["cache_hits"] == sent and cost["all"]["cache_hits"] == 0


def test_without_the_cache_every_call_goes_to_the_server_and_is_logged_off(chat_server, tmp_path):
    result = _ablate(_grid(tmp_path, chat_server.url), tmp_path / "a")
    assert result.exit_code == 0, result.output
    calls = _calls(tmp_path / "a")
    assert {c["cache"] for c in calls} == {"off"} and len(chat_server.seen) == len(calls)


def test_cost_per_run_and_per_sweep_from_the_price_file(chat_server, tmp_path, monkeypatch):
    prices = tmp_path / "prices.toml"
    prices.write_text(PRICES)
    monkeypatch.setenv("LLMNAV_PRICES", str(prices))
    result = _ablate(_grid(tmp_path, chat_server.url), tmp_path / "a")
    assert result.exit_code == 0, result.output
    summaries = _summaries(tmp_path / "a")
    for summary in summaries:  # tokens × price: 1000 prompt tokens at 1000 USD per million per call
        assert summary["cost_usd"] == pytest.approx(summary["llm_calls"] * PROMPT_TOKENS * 1000.0 / 1e6)
        assert summary["tokens"]["prompt"] == summary["llm_calls"] * PROMPT_TOKENS
    scored = CliRunner().invoke(app, ["score", str(tmp_path / "a"), "--table", "cost", "--format", "json"])
    records = {r["condition"]: r for r in json.loads(scored.stdout)[0]["records"]}
    assert records["all runs"]["cost_usd"] == pytest.approx(sum(s["cost_usd"] for s in summaries))
    # the same logs repriced with the bundled table, where model "m" on a loopback server is free
    monkeypatch.delenv("LLMNAV_PRICES")
    bundled = Path(__file__).parents[2] / "llmnav" / "backends" / "prices.toml"
    scored = CliRunner().invoke(
        app, ["score", str(tmp_path / "a"), "--table", "cost", "--format", "json", "--prices", str(bundled)]
    )
    assert json.loads(scored.stdout)[0]["records"][-1]["cost_usd"] == 0.0


def test_max_cost_refuses_a_sweep_estimated_above_it(chat_server, tmp_path):
    prices = tmp_path / "prices.toml"
    prices.write_text(PRICES)
    grid = _grid(tmp_path, chat_server.url)
    # 2 episodes × 1000 prompt tokens at 1000 USD per million = 2 USD > 1.5
    refused = _ablate(grid, tmp_path / "a", "--prices", str(prices), "--max-cost", "1.5", "--episode-tokens", "1000,0")
    assert refused.exit_code == 2, refused.output
    assert "estimated at 2.0000 USD" in refused.output and "nothing was run" in refused.output
    assert chat_server.seen == [] and not list((tmp_path / "a").glob("*/run.jsonl"))
    # no basis for an estimate (no token assumption, no finished episode): refused too, naming the option
    unknown = _ablate(grid, tmp_path / "a", "--prices", str(prices), "--max-cost", "100")
    assert unknown.exit_code == 2 and "--episode-tokens" in unknown.output
    assert chat_server.seen == []
    # a model the price table does not list, on this machine, is free: a limit of 0 lets it run
    other = tmp_path / "other.toml"
    other.write_text('as_of = 2026-01-01\n[openai]\n"x" = { prompt = 1.0, completion = 1.0 }\n')
    free_here = _ablate(grid, tmp_path / "b", "--prices", str(other), "--max-cost", "0")
    assert free_here.exit_code == 0, free_here.output
    assert len(chat_server.seen) == len(_calls(tmp_path / "b")) > 0


def test_max_cost_stops_a_sweep_that_reaches_it_and_the_sweep_resumes(chat_server, tmp_path):
    prices = tmp_path / "prices.toml"
    prices.write_text(PRICES)
    grid, out = _grid(tmp_path, chat_server.url, trials=2), tmp_path / "a"
    # estimated 4 × 0.25 USD = 1 USD, but each episode costs 1 USD: the limit of 2 is reached after two
    stopped = _ablate(grid, out, "--prices", str(prices), "--max-cost", "2", "--episode-tokens", "250,0")
    assert stopped.exit_code == 5, stopped.output
    assert "limit is reached" in stopped.output and "2 episode(s) not run" in stopped.output
    manifest = json.loads((out / "manifest.json").read_text())
    statuses = sorted(e["status"] for e in manifest["episodes"])
    assert statuses == ["done", "done", "pending", "pending"]
    assert sum(e["cost_usd"] or 0 for e in manifest["episodes"]) == pytest.approx(2.0)
    assert len(chat_server.seen) == 2
    # resumed: estimated from the finished episodes (1 USD each), 2 left = 2 USD ≤ 2
    resumed = _ablate(grid, out, "--prices", str(prices), "--max-cost", "2")
    assert resumed.exit_code == 0, resumed.output
    manifest = json.loads((out / "manifest.json").read_text())
    assert [e["status"] for e in manifest["episodes"]] == ["done"] * 4
    assert len(chat_server.seen) == 4  # the finished episodes were not run again
    # a limit below what is left is refused up front, even when resuming
    again = _ablate(grid, tmp_path / "b", "--prices", str(prices), "--max-cost", "3")
    assert again.exit_code == 2 and "--episode-tokens" in again.output


@pytest.mark.parametrize(
    "text, problem",
    [
        ('as_of = 2026-01-01\n[openai]\n"m" = { prompt = -1.0, completion = 1.0 }\n', "openai.m.prompt: -1.0"),
        ('as_of = 2026-01-01\n[openai]\n"m" = { prompt = "cheap", completion = 1.0 }\n', "'cheap' is not a price"),
        ('as_of = 2026-01-01\n[openai]\n"m" = { prompt = nan, completion = 1.0 }\n', "nan is not a price"),
        ('as_of = 2026-01-01\n[openai]\n"m" = { prompt = 1.0 }\n', "openai.m must be"),
        ('[openai]\n"m" = { prompt = 1.0, completion = 1.0 }\n', "'as_of' must be the date"),
        ("as_of = 2026-01-01\nopenai = 3\n", "'openai' must be a table"),
        ("as_of = [\n", "not valid TOML"),
    ],
)
def test_a_bad_price_file_is_one_line_and_exit_2(tmp_path, monkeypatch, text, problem):
    prices = tmp_path / "prices.toml"
    prices.write_text(text)
    out = tmp_path / "run"
    args = ["drive", "--scenario", str(SMALL_ROOM), "--task-id", "T1", "--planner", "oracle", "--out", str(out)]
    for how in (["--prices", str(prices)], []):
        if not how:
            monkeypatch.setenv("LLMNAV_PRICES", str(prices))
        result = CliRunner().invoke(app, [*args, *how])
        assert result.exit_code == 2, result.output
        lines = result.output.strip().splitlines()
        assert len(lines) == 1 and problem in lines[0] and "Traceback" not in result.output
        assert not out.exists()
    scored = CliRunner().invoke(app, ["score", str(tmp_path), "--prices", str(prices)])
    assert scored.exit_code == 2 and problem in scored.output


def test_estimates_and_lookups(tmp_path):
    from llmnav.backends.prices import estimate, load_prices, run_cost

    table = load_prices(Path(__file__).parents[2] / "llmnav" / "backends" / "prices.toml")
    paid = {"provider": "openai", "model": "gpt-4o-mini-2024-07-18", "local": False}  # a dated snapshot
    cost, note = estimate(paid, 1_000_000, 100_000, table)
    assert cost == pytest.approx(0.15 + 0.06) and "openai:gpt-4o-mini" in note
    cost, note = estimate({"provider": "openai", "model": "gpt-99", "local": False}, 10, 10, table)
    assert cost is None and "no price for openai:gpt-99" in note  # unknown, never 0
    cost, _ = estimate({"provider": "ollama", "model": "llama3.1", "local": True}, 10, 10, table)
    assert cost == 0.0  # an unlisted model on this machine
    cost, _ = estimate({"free": "policy backend"}, 10**9, 10**9, table)
    assert cost == 0.0
    calls = [
        {"cache": "miss", "reply": {"prompt_tokens": 1000, "completion_tokens": 100}},
        {"cache": "hit", "reply": {"prompt_tokens": 1000, "completion_tokens": 100}},
    ]
    run = run_cost({"billing": paid}, calls, table)
    assert run["cache_hits"] == 1 and run["cost_usd"] == pytest.approx((1000 * 0.15 + 100 * 0.6) / 1e6)
    no_counts = run_cost({"billing": paid}, [{"cache": "miss", "reply": {"text": "x"}}], table)
    assert no_counts["cost_usd"] is None and "without token counts" in no_counts["cost_note"]
    old = run_cost({"backend": "openai:gpt-4o"}, calls, table)  # a run from before billing was recorded
    assert old["cost_usd"] is None


def test_drive_through_the_cache_says_what_it_cost(chat_server, tmp_path, monkeypatch):
    prices = tmp_path / "prices.toml"
    prices.write_text(PRICES)
    args = ["drive", "--scenario", str(SMALL_ROOM), "--task-id", "T1", "--planner", "hybrid", "--decide", "generate",
            "--sensing", "lidar", "-o", "max_iterations=1", "--backend", f"openai:m@{chat_server.url}/v1",
            "--cache", str(tmp_path / "cache"), "--prices", str(prices), "--quiet"]  # fmt: skip
    first = CliRunner().invoke(app, [*args, "--out", str(tmp_path / "a")])
    assert "cost 1.0000 USD (1 model call(s))" in first.output, first.output
    second = CliRunner().invoke(app, [*args, "--out", str(tmp_path / "b")])
    assert "cost 0.0000 USD (1 model call(s), 1 from the cache)" in second.output, second.output
    assert len(chat_server.seen) == 1
    summary = json.loads((tmp_path / "b" / "summary.json").read_text())
    assert summary["tokens"] == {"prompt": 1000, "completion": 50, "paid_prompt": 0, "paid_completion": 0}


@pytest.mark.parametrize(
    "url, local",
    [
        ("http://127.0.0.1:8080/v1", True),
        ("http://localhost:11434", True),
        ("http://[::1]:8080/v1", True),
        ("http://10.0.0.7:8000/v1", True),
        ("http://192.168.1.20:11434", True),
        ("https://api.openai.com/v1", False),
        ("https://generativelanguage.googleapis.com", False),
        ("http://8.8.8.8:8080/v1", False),
        ("https://localhost.example.com/v1", False),
    ],
)
def test_which_servers_are_local(url, local):
    from llmnav.backends.prices import local_server

    assert local_server(url) is local


def test_a_dated_snapshot_takes_the_longest_listed_name():
    import datetime

    from llmnav.backends.prices import parse_prices

    table = parse_prices(
        {"as_of": datetime.date(2026, 1, 1), "openai": {"gpt-4o": {"prompt": 2, "completion": 8},
                                                        "gpt-4o-mini": {"prompt": 1, "completion": 4}}},
        "t.toml",
    )  # fmt: skip
    assert table.lookup("openai", "gpt-4o-mini-2024-07-18") == ("gpt-4o-mini", table.prices["openai"]["gpt-4o-mini"])
    assert table.lookup("openai", "gpt-4o-2024-08-06")[0] == "gpt-4o"
    assert table.lookup("openai", "gpt-4omega") is None and table.lookup("gemini", "gpt-4o") is None
