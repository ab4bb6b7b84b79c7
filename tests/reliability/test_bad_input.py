"""Bad input: malformed scenario files, hand-edited replay logs, unknown backends, bad CLI values, a
missing model file, an output folder that cannot be written.

Property: exit status 2, one line `error: ...` (no traceback), no run folder started for the failed
command, and a run written before (in the same folder tree) left byte for byte as it was.
Typer's own type errors (`--lidar-sectors abc`) print Click's usage box instead of one line; those are
checked for exit 2, the flag's name and no traceback.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from llmnav.cli import app
from llmnav.runs.runlog import RunLog

CATEGORY = "bad input"
SMALL_ROOM = Path(__file__).parents[1] / "runner" / "small_room.yaml"


def tree_digest(root: Path) -> dict[str, str]:
    return {
        str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


@pytest.fixture(scope="module")
def workspace(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder with one finished run (`runs/prior`) and a good replay script."""
    root = tmp_path_factory.mktemp("bad-input")
    result = CliRunner().invoke(
        app, ["drive", "--planner", "oracle", "--scenario", str(SMALL_ROOM), "--task-id", "T1",
              "--out", str(root / "runs" / "prior"), "--json"]
    )
    assert result.exit_code == 0, result.output
    with RunLog(root / "script", {"note": "replies"}) as log:
        log.event("llm_call", step=1, purpose="action", request={"messages": []},
                  reply={"text": '{"action": {"command": "COMPLETE", "parameters": 0}}', "latency_s": 0.1})
    return root


def scenario_file(root: Path, name: str, text: str | bytes) -> str:
    path = root / "scenarios" / name
    path.parent.mkdir(exist_ok=True)
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    return str(path)


def replay_file(root: Path, name: str, edit: Callable[[list[str]], list[str]]) -> str:
    lines = (root / "script" / "run.jsonl").read_text().splitlines()
    folder = root / "edited" / name
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "run.jsonl").write_text("\n".join(edit(lines)) + "\n")
    return f"replay:{folder}"


SMALL = SMALL_ROOM.read_text()


def cases(root: Path) -> dict[str, list[str]]:
    """Case name → drive arguments (without --out). Built lazily: files are written into `root`."""
    drive = ["drive", "--planner", "stepwise", "--sensing", "lidar", "--task-id", "T1"]
    small = ["--scenario", str(SMALL_ROOM)]
    with_scenario = lambda name, text: [*drive, "--scenario", scenario_file(root, name, text)]  # noqa: E731
    with_replay = lambda name, edit: [*drive, *small, "--backend", replay_file(root, name, edit)]  # noqa: E731
    return {
        "scenario: YAML syntax": with_scenario("syntax.yaml", "name: [unclosed\nrobot: pr2\n"),
        "scenario: unknown key": with_scenario("key.yaml", SMALL + "\nteleporters: 3\n"),
        "scenario: wrong type": with_scenario("type.yaml", SMALL.replace("{x: [0.0, 8.0]", "{x: nine")),
        "scenario: empty file": with_scenario("empty.yaml", ""),
        "scenario: binary": with_scenario("binary.yaml", bytes(range(256)) * 4),
        "scenario: a list": with_scenario("list.yaml", "- 1\n- 2\n"),
        "scenario: unknown robot": with_scenario("robot.yaml", SMALL.replace("robot: pr2", "robot: tank")),
        "scenario: missing file": [*drive, "--scenario", str(root / "nope.yaml")],
        "scenario: a folder": [*drive, "--scenario", str(root)],
        "replay: garbage line": with_replay("garbage", lambda ls: [ls[0], "{not json", *ls[1:]]),
        "replay: reply text a number": with_replay(
            "number", lambda ls: [ls[0], ls[1].replace('"text": "', '"text": 7, "x": "')]
        ),
        "replay: latency a string": with_replay(
            "latency", lambda ls: [ls[0], ls[1].replace('"latency_s": 0.1', '"latency_s": "fast"')]
        ),
        "replay: torn middle line": with_replay("torn", lambda ls: [ls[0], ls[1][:40], ls[1]]),
        "replay: empty file": with_replay("empty", lambda ls: []),
        "replay: missing folder": [*drive, *small, "--backend", f"replay:{root / 'no-such-run'}"],
        "backend: unknown name": [*drive, *small, "--backend", "nosuch:model"],
        "backend: empty spec": [*drive, *small, "--backend", ""],
        "backend: bad replay flag": [*drive, *small, "--backend", "openai:m", "--replay-loose"],
        "backend: missing model file": [*drive, *small, "--backend", "local:/nonexistent.gguf"],
        "backend: model file is not GGUF": [*drive, *small, "--backend", f"local:{SMALL_ROOM}"],
        "backend: openai without key": [*drive, *small, "--backend", "openai:gpt-4o-mini"],
        "backend: gemini without key": [*drive, *small, "--backend", "gemini"],
        "cli: --history 7": [*drive, *small, "--history", "7"],
        "cli: --lidar-sectors 0": [*drive, *small, "--lidar-sectors", "0"],
        "cli: --lidar-fov 720": [*drive, *small, "--lidar-fov", "720"],
        "cli: --start-pose 99": [*drive, *small, "--start-pose", "99"],
        "cli: --start-pose 0": [*drive, *small, "--start-pose", "0"],
        "cli: --sensing sonar": [*drive, *small, "--sensing", "sonar"],
        "cli: --obstacle abc": [*drive, *small, "--obstacle", "abc"],
        "cli: --obstacle 1,2,3": [*drive, *small, "--obstacle", "1,2,3"],
        "cli: --planner nope": [*drive, *small, "--planner", "nope"],
        "cli: --max-iterations 0": [*drive, *small, "--max-iterations", "0"],
        "cli: --assist maybe": [*drive, *small, "--assist", "maybe"],
        "cli: --prompt nosuch": [*drive, *small, "--prompt", "nosuch"],
        "cli: --task-id T99": [*drive, *small[:], "--task-id", "T99"],
        "cli: --task and --task-id": [*drive, *small, "--task", "Go to the red box"],
        "cli: no task": ["drive", *small, "--planner", "oracle"],
    }


TYPER_ERRORS = {"cli: --lidar-sectors abc": ["--lidar-sectors", "abc"], "cli: --seed x": ["--seed", "x"]}


def check(result: Any, tally: Any, case: str, out: Path, before: dict[str, str], root: Path) -> list[str]:
    problems = []
    output = result.output.strip()
    if result.exit_code != 2:
        problems.append(f"exit {result.exit_code}")
    if result.exception is not None and not isinstance(result.exception, SystemExit):
        problems.append(f"raised {type(result.exception).__name__}: {result.exception}")
        tally.add(CATEGORY, crashes=1)
    if len(output.splitlines()) != 1 or not output.startswith("error: "):
        problems.append(f"not one error line: {output[:400]!r}")
    if out.exists():
        problems.append("a run folder was started")
    if tree_digest(root / "runs" / "prior") != before:
        problems.append("files written before were changed")
        tally.add(CATEGORY, lost=1)
    return problems


def test_bad_inputs_give_one_line_and_exit_2(workspace: Path, tally: Any) -> None:
    before = tree_digest(workspace / "runs" / "prior")
    failures = {}
    table = cases(workspace)
    for name, args in table.items():
        out = workspace / "runs" / f"new-{len(failures)}-{abs(hash(name)) % 10**6}"
        result = CliRunner().invoke(app, [*args, "--out", str(out)])
        problems = check(result, tally, name, out, before, workspace)
        if problems:
            failures[name] = problems
    for name, args in TYPER_ERRORS.items():
        result = CliRunner().invoke(app, ["drive", "--task-id", "T1", *args])
        if result.exit_code != 2 or args[0] not in result.output or "Traceback" in result.output:
            failures[name] = [result.output[-300:]]
    tally.add(CATEGORY, tried=len(table) + len(TYPER_ERRORS))
    tally.note(CATEGORY, "drive cases", len(table) + len(TYPER_ERRORS))
    assert not failures, json.dumps(failures, indent=1)


def unwritable_outs(root: Path) -> dict[str, Path]:
    """Output folders that cannot be created or written (root ignores permission bits, so also a path
    below a regular file and one inside /proc)."""
    blocker = root / "a-file"
    blocker.write_text("not a folder\n")
    outs = {"below a regular file": blocker / "run", "inside /proc": Path("/proc/llmnav-reliability/run")}
    import os

    if os.geteuid() != 0:
        readonly = root / "readonly"
        readonly.mkdir(exist_ok=True)
        readonly.chmod(0o555)
        outs["read-only folder"] = readonly / "run"
    return outs


def test_unwritable_output_folder(workspace: Path, tally: Any) -> None:
    before = tree_digest(workspace / "runs" / "prior")
    failures = {}
    outs = unwritable_outs(workspace)
    for name, out in outs.items():
        for planner in ("oracle", "stepwise"):
            backend = f"replay:{workspace / 'script'}?loose"
            result = CliRunner().invoke(
                app, ["drive", "--planner", planner, "--backend", backend, "--sensing", "lidar",
                      "--scenario", str(SMALL_ROOM), "--task-id", "T1", "--out", str(out)]
            )
            problems = check(result, tally, name, out, before, workspace)
            if problems:
                failures[f"{name} ({planner})"] = problems
    # ablate and score into or from places they cannot use
    extra = {
        "ablate --out below a file": ["ablate", "--scenario", str(SMALL_ROOM), "--tasks", "T1", "--poses", "1",
                                      "--planner", "oracle", "--out", str(outs["below a regular file"])],
        "ablate --trials 0": ["ablate", "--scenario", str(SMALL_ROOM), "--trials", "0"],
        "ablate --lidar-sectors x": ["ablate", "--scenario", str(SMALL_ROOM), "--lidar-sectors", "x,y"],
        "ablate --grid missing": ["ablate", "--grid", str(workspace / "nogrid.yaml")],
        "score missing folder": ["score", str(workspace / "nothing-here")],
        "score edited log": ["score", replay_file(workspace, "score-garbage",
                                                  lambda ls: [ls[0], "{oops", *ls[1:]]).removeprefix("replay:")],
        "score --out below a file": ["score", str(workspace / "runs"), "--out",
                                     str(outs["below a regular file"])],
    }
    for name, args in extra.items():
        result = CliRunner().invoke(app, args)
        output = result.output.strip()
        if result.exit_code != 2 or "Traceback" in output or not output.splitlines()[-1:] or (
            "error" not in output.lower()
        ):
            failures[name] = [f"exit {result.exit_code}: {output[-300:]}"]
        elif not name.startswith("ablate --trials") and len(output.splitlines()) != 1:
            failures[name] = [f"not one line: {output[-300:]}"]
    if tree_digest(workspace / "runs" / "prior") != before:
        failures["prior run"] = ["changed"]
        tally.add(CATEGORY, lost=1)
    tally.add(CATEGORY, tried=2 * len(outs) + len(extra))
    assert not failures, json.dumps(failures, indent=1)
