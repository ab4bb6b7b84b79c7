"""Mode fallback: `--decide auto` with a server that cannot score (no `/tokenize`) generates, and says so:
the run's condition and every table show `decide=generate (fallback)`, never `decide=auto` over runs that
generated, so tables do not pool scored and generated runs. A server failing `/tokenize` under
`--decide score` is a server failure (exit 4), not bad input (exit 2). Counted as category "mode fallback".
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from llmnav.cli import app

CATEGORY = "mode fallback"
SMALL_ROOM = str(Path(__file__).parents[1] / "runner" / "small_room.yaml")
EXIT_SERVER_FAILED = 4


def _cli(*args: str) -> Any:
    result = CliRunner().invoke(app, list(args))
    crashed = result.exception is not None and not isinstance(result.exception, SystemExit)
    assert not crashed, repr(result.exception)
    return result


def _chat_server(server: Any, tokenize_status: int) -> None:
    def answer(seen: Any) -> Any:
        if seen.path.endswith("/tokenize"):
            return server.reply(tokenize_status, {"error": {"message": "no tokenizer here"}})
        text = '{"option": 1}'
        return server.reply(200, {"choices": [{"message": {"role": "assistant", "content": text}}]})

    server.default = answer


def test_a_fallback_to_generation_is_the_condition_in_every_table(tmp_path: Path, server: Any, tally: Any) -> None:
    tally.add(CATEGORY, tried=3)
    _chat_server(server, 404)  # an OpenAI-compatible server without llama.cpp's /tokenize
    runs = tmp_path / "runs"
    for decide in ("auto", "generate"):
        result = _cli("drive", "--planner", "hybrid", "--backend", f"openai:m@{server.url}/v1", "-o",
                      f"decide={decide}", "-o", "max_iterations=2", "--scenario", SMALL_ROOM, "--task-id", "T1",
                      "--sensing", "lidar", "--out", str(runs / decide), "--quiet")  # fmt: skip
        assert result.exit_code in (0, 1, 3), result.output
    assert any(s.path.endswith("/chat/completions") for s in server.seen)
    summary = json.loads((runs / "auto" / "summary.json").read_text())
    marked = summary["condition"]["decide"] == "generate (fallback)"
    tally.add(CATEGORY, failures=int(not marked))
    assert marked, summary["condition"]
    plain = json.loads((runs / "generate" / "summary.json").read_text())
    assert plain["condition"]["decide"] == "generate", plain["condition"]  # asked for: no mark

    scored = _cli("score", str(runs), "--by", "decide")
    shown = "decide=generate (fallback)" in scored.stdout and "decide=auto" not in scored.stdout
    tally.add(CATEGORY, failures=int(not shown))
    assert scored.exit_code == 0 and shown, scored.stdout
    records = json.loads(_cli("score", str(runs), "--by", "decide", "--format", "json").stdout)
    episodes = {r["decide"] for t in records if t["name"] == "episodes" for r in t["records"]}
    tally.add(CATEGORY, failures=int(episodes != {"generate", "generate (fallback)"}))
    assert episodes == {"generate", "generate (fallback)"}, episodes


@pytest.mark.parametrize("decide", ["score", "auto"])
def test_a_tokenize_failure_under_score_is_exit_4(decide: str, tmp_path: Path, server: Any, tally: Any) -> None:
    tally.add(CATEGORY, tried=1)
    _chat_server(server, 500)
    result = _cli("drive", "--planner", "hybrid", "--backend", f"openai:m@{server.url}/v1", "-o", f"decide={decide}",
                  "--scenario", SMALL_ROOM, "--task-id", "T1", "--sensing", "lidar", "--out", str(tmp_path / "run"),
                  "--quiet")  # fmt: skip
    tally.add(CATEGORY, failures=int(result.exit_code != EXIT_SERVER_FAILED))
    assert result.exit_code == EXIT_SERVER_FAILED, result.output
