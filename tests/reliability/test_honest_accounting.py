"""Honest accounting: exit codes and grids that say what happened. `ablate` exits non-zero when an episode
failed (it exited 0 on "2 error(s)"); one value written two ways (`0.3,0.30`, `8,08,8.0`, `T1,t1`) or a
key given twice (`-o K=a -o K=b`) is refused instead of running one condition twice or silently keeping
one; a URL with no host (`openai:m@http://`) is bad input with no folder written (it became
`http://http:` and a run folder); a server failing `/tokenize` is a server failure (exit 4), never bad
input (exit 2) nor a silent switch to generation. Counted as category "honest accounting".
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from llmnav.cli import app

CATEGORY = "honest accounting"
SMALL_ROOM = str(Path(__file__).parents[1] / "runner" / "small_room.yaml")
EXIT_BAD_INPUT, EXIT_SERVER_FAILED = 2, 4


def _cli(*args: str) -> Any:
    result = CliRunner().invoke(app, list(args))
    crashed = result.exception is not None and not isinstance(result.exception, SystemExit)
    assert not crashed, repr(result.exception)
    return result


def test_ablate_exits_non_zero_when_an_episode_failed(tmp_path: Path, server: Any, tally: Any) -> None:
    tally.add(CATEGORY, tried=1)
    server.default = server.reply(400, {"error": {"message": "model 'm' not found"}})  # not retried
    out = tmp_path / "sweep"
    result = _cli("ablate", "--scenario", SMALL_ROOM, "--planner", "stepwise", "--tasks", "T1", "--poses", "1",
                  "--backend", f"openai:m@{server.url}/v1", "--sensing", "lidar", "--out", str(out))  # fmt: skip
    manifest = json.loads((out / "manifest.json").read_text())
    statuses = [e["status"] for e in manifest["episodes"]]
    assert statuses == ["error"], statuses
    tally.add(CATEGORY, failures=int(result.exit_code == 0))
    assert result.exit_code != 0 and "1 error(s)" in result.output, result.output


@pytest.mark.parametrize(
    "args",
    [
        ["--planner", "hybrid", "-o", "alpha=0.3,0.30"],
        ["--planner", "stepwise", "--lidar-sectors", "8,08,8.0"],
        ["--planner", "oracle", "--tasks", "T1,t1"],
        ["--planner", "oracle", "--tasks", "T1,T1"],
        ["--planner", "stepwise", "-o", "max_iterations=3", "-o", "max_iterations=4"],
    ],
    ids=["alpha 0.3,0.30", "sectors 8,08,8.0", "tasks T1,t1", "tasks T1,T1", "-o K twice"],
)
def test_one_value_written_twice_is_refused(args: list[str], tmp_path: Path, tally: Any) -> None:
    tally.add(CATEGORY, tried=1)
    flags = ["--tasks", "T1"] if "--tasks" not in args else []
    result = _cli("ablate", "--scenario", SMALL_ROOM, *flags, "--poses", "1", *args, "--dry-run",
                  "--out", str(tmp_path / "sweep"))  # fmt: skip
    tally.add(CATEGORY, failures=int(result.exit_code != EXIT_BAD_INPUT))
    assert result.exit_code == EXIT_BAD_INPUT, result.output
    assert "same value" in result.output or "given twice" in result.output, result.output


def test_a_repeated_option_is_refused_by_drive_and_poses_are_counted_once(tmp_path: Path, tally: Any) -> None:
    tally.add(CATEGORY, tried=2)
    out = tmp_path / "run"
    drive = _cli("drive", "--planner", "oracle", "--scenario", SMALL_ROOM, "--task-id", "T1", "-o", "seed=1",
                 "-o", "seed=2", "--out", str(out))  # fmt: skip
    assert drive.exit_code == EXIT_BAD_INPUT and "given twice" in drive.output and not out.exists(), drive.output
    plan = _cli("ablate", "--scenario", SMALL_ROOM, "--planner", "oracle", "--tasks", "T1", "--poses", "1,1,01",
                "--dry-run", "--out", str(tmp_path / "sweep"))  # fmt: skip
    assert plan.exit_code == 0 and "1 episodes" in plan.output, plan.output


@pytest.mark.parametrize("url", ["http://", "https:///", "http://  "])
def test_a_url_without_host_is_bad_input_and_writes_nothing(url: str, tmp_path: Path, tally: Any) -> None:
    tally.add(CATEGORY, tried=2)
    out = tmp_path / "run"
    drive = _cli("drive", "--planner", "stepwise", "--backend", f"openai:m@{url}", "--scenario", SMALL_ROOM,
                 "--task-id", "T1", "--out", str(out))  # fmt: skip
    assert drive.exit_code == EXIT_BAD_INPUT and "no host" in drive.output, drive.output
    assert not out.exists()
    sweep = tmp_path / "sweep"
    ablate = _cli("ablate", "--scenario", SMALL_ROOM, "--planner", "stepwise", "--tasks", "T1", "--poses", "1",
                  "--backend", f"openai:m@{url}", "--out", str(sweep))  # fmt: skip
    assert ablate.exit_code == EXIT_BAD_INPUT and "no host" in ablate.output, ablate.output
    assert not sweep.exists()


@pytest.mark.parametrize("url", ["http://", "https:///"])
def test_backends_check_of_a_url_without_host_is_bad_input(
    url: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, tally: Any
) -> None:
    """`backends --check openai:m@http://` printed a failed check and exited 1, as if a server were down."""
    tally.add(CATEGORY, tried=1)
    monkeypatch.chdir(tmp_path)
    result = _cli("backends", "--check", f"openai:m@{url}")
    ok = result.exit_code == EXIT_BAD_INPUT and "no host" in result.output and not any(tmp_path.iterdir())
    tally.add(CATEGORY, failures=int(not ok))
    assert ok, (result.exit_code, result.output)


@pytest.mark.parametrize("decide", ["score", "auto"])
def test_a_tokenize_failure_is_a_server_failure(decide: str, tmp_path: Path, server: Any, tally: Any) -> None:
    """One HTTP 500 from /tokenize: `--decide score` exited 2 (bad input), `--decide auto` went on generating
    while its condition said auto."""
    tally.add(CATEGORY, tried=1)

    def answer(seen: Any) -> Any:
        if seen.path.endswith("/tokenize"):
            return server.reply(500, {"error": {"message": "tokenizer crashed"}})
        text = '{"option": 1}'
        return server.reply(200, {"choices": [{"message": {"role": "assistant", "content": text}}]})

    server.default = answer
    out = tmp_path / "run"
    result = _cli("drive", "--planner", "hybrid", "--backend", f"openai:m@{server.url}/v1", "-o",
                  f"decide={decide}", "--scenario", SMALL_ROOM, "--task-id", "T1", "--sensing", "lidar",
                  "--out", str(out), "--quiet")  # fmt: skip
    tally.add(CATEGORY, failures=int(result.exit_code != EXIT_SERVER_FAILED))
    assert result.exit_code == EXIT_SERVER_FAILED, result.output
    assert not any(s.path.endswith("/chat/completions") for s in server.seen), "it generated instead"
