"""What llmnav prints cannot be hijacked or emptied: control characters from files, models and servers are
shown escaped, Rich markup in them is shown as written, `COLUMNS=0` does not empty machine output, and a
reader that goes away (`| head -1`) or a full disk ends with the right exit code and at most one line.

The console script runs in a subprocess (its real stdout, environment and exit code), CliRunner elsewhere.
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
from llmnav.runs.runlog import RunLog

ENTRY = "from llmnav.cli import main; main()"
SMALL_ROOM = str(Path(__file__).parent / "runner" / "small_room.yaml")
HOSTILE = "\x1b]0;PWNED\x07\x1b[2J"


def llmnav(*args: str, env: dict[str, str] | None = None, **kwargs: object) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-c", ENTRY, *args],
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, **(env or {})},
        **kwargs,  # type: ignore[arg-type]
    )


def no_control(text: str) -> bool:
    return not any(ch in text for ch in ("\x1b", "\x07", "\x9b"))


def hostile_scenario(tmp_path: Path) -> Path:
    text = Path(SMALL_ROOM).read_text()
    # YAML forbids raw control characters; its escapes \e (ESC) and \a (BEL) put them in the loaded text
    text = text.replace("text: Go to the red box", 'text: "Go to the red box \\e]0;PWNED\\a\\e[2J [/] [bold]x"')
    path = tmp_path / "hostile[v2].yaml"
    path.write_text(text)
    return path


# --- 9. control characters from files and models never reach the terminal raw -------------------------


def test_task_text_and_model_reasoning_are_escaped(tmp_path: Path) -> None:
    reply = {"goal": "box", "reasoning": f"I see {HOSTILE} and [/] a [red]box", "scene_description": "room",
             "action": {"command": "COMPLETE", "parameters": 0}}
    with RunLog(tmp_path / "script", {"note": "hostile replies"}) as log:
        log.event("llm_call", step=1, purpose="action", request={"messages": []},
                  reply={"text": json.dumps(reply), "latency_s": 0.0})
    scenario = hostile_scenario(tmp_path)
    result = llmnav("drive", "--planner", "stepwise", "--backend", f"replay:{tmp_path / 'script'}?loose",
                    "--scenario", str(scenario), "--task-id", "T1", "--sensing", "lidar",
                    "--out", str(tmp_path / "run"), env={"COLUMNS": "400"})
    assert "Traceback" not in result.stderr, result.stderr[-2000:]
    shown = result.stdout + result.stderr
    assert no_control(shown), repr(shown[:500])
    assert "\\x1b]0;PWNED\\x07" in shown  # visible, escaped
    assert "[/] a [red]box" in shown  # markup in model text is shown as written


def test_scenario_show_escapes_file_text(tmp_path: Path) -> None:
    result = llmnav("scenarios", "show", str(hostile_scenario(tmp_path)), env={"COLUMNS": "400"})
    assert result.returncode == 0, result.stderr
    assert no_control(result.stdout) and "[/] [bold]x" in result.stdout


def test_error_lines_escape_server_and_file_text(tmp_path: Path) -> None:
    bad = tmp_path / f"bad{HOSTILE}[bold].yaml"
    bad.write_text("name: [unclosed\n")
    result = llmnav("scenarios", "show", str(bad))
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert no_control(result.stderr) and "[bold].yaml" in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1


# --- 10. Rich markup in non-literal text is printed, never interpreted ----------------------------------


def test_markup_in_paths_is_shown_as_written(tmp_path: Path) -> None:
    missing = tmp_path / "results[v2]"
    result = CliRunner().invoke(app, ["score", str(missing)])
    assert result.exit_code == 2 and f"{missing}: no such file" in " ".join(result.output.split())
    result = CliRunner().invoke(app, ["score", str(tmp_path / "a[/]b")])
    assert result.exit_code == 2 and "MarkupError" not in result.output and "a[/]b" in result.output


def test_ray_install_hint_keeps_its_extra(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "ray", None)
    result = CliRunner().invoke(app, ["ablate", "--scenario", SMALL_ROOM, "--tasks", "T1", "--poses", "1",
                                      "--planner", "oracle", "--ray", "auto", "--out", str(tmp_path / "ab")])
    assert result.exit_code == 2 and "pip install 'llmnav[ray]'" in result.output, result.output


# --- 11. machine-readable output does not depend on the terminal width -----------------------------------


def test_zero_columns_do_not_empty_the_output(tmp_path: Path) -> None:
    env = {"COLUMNS": "0"}
    run = tmp_path / "run"
    drive = llmnav("drive", "--planner", "oracle", "--scenario", SMALL_ROOM, "--task-id", "T1",
                   "--out", str(run), "--json", env=env)
    assert drive.returncode == 0, drive.stderr
    assert json.loads(drive.stdout)["outcome"] == "completed"
    score = llmnav("score", str(run), "--format", "json", env=env)
    assert score.returncode == 0, score.stderr
    assert json.JSONDecoder().raw_decode(score.stdout)[0]  # the data first (status lines: the score issue)
    listing = llmnav("scenarios", env=env)
    assert listing.returncode == 0 and "factory" in listing.stdout
    error = llmnav("drive", "--task-id", "T1", "--lidar-sectors", "0", env=env)
    assert error.returncode == 2 and "lidar-sectors" in error.stderr, error.stderr


# --- 12. a reader that goes away is not a failure; a full disk is one line -------------------------------


def test_closed_stdout_keeps_the_exit_code(tmp_path: Path) -> None:
    cmd = f"{sys.executable} -c '{ENTRY}' scenarios show factory | head -1 >/dev/null; echo ${{PIPESTATUS[0]}}"
    result = subprocess.run(["bash", "-c", cmd], capture_output=True, text=True, timeout=120,
                            env={**os.environ, "COLUMNS": "100"})
    assert result.stdout.strip() == "0", result.stderr
    assert "Traceback" not in result.stderr and "BrokenPipe" not in result.stderr, result.stderr


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full")
def test_full_stdout_is_one_line_and_non_zero(tmp_path: Path) -> None:
    with open("/dev/full", "w") as full:
        result = subprocess.run([sys.executable, "-c", ENTRY, "scenarios", "show", "factory"], stdout=full,
                                stderr=subprocess.PIPE, text=True, timeout=120)
    assert result.returncode != 0
    assert "Traceback" not in result.stderr and len(result.stderr.strip().splitlines()) == 1, result.stderr
    assert "No space left" in result.stderr
