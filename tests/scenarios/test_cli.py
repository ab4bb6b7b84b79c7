"""`llmnav scenarios` through the CLI app: list, show, plot, and one-line errors for bad files."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from llmnav.cli import app
from llmnav.commands.common import console

runner = CliRunner()


@pytest.fixture(autouse=True)
def wide_console(monkeypatch: pytest.MonkeyPatch) -> None:
    """Tables as on a wide terminal, so cell text is not wrapped mid-phrase."""
    monkeypatch.setattr(console, "_width", 240)  # restored exactly afterwards (None = follow the terminal)


# A small valid scenario the bad variants below break one thing at a time.
GOOD: dict = {
    "name": "tiny",
    "robot": "burger",
    "bounds": {"x": [0, 4], "y": [0, 4]},
    "obstacles": [{"center": [2.0, 2.0], "size": [0.5, 0.5]}],
    "objects": [{"id": "door", "label": "door", "center": [3.5, 3.5], "size": [0.4, 0.1], "solid": False}],
    "tasks": [
        {
            "id": "X1",
            "text": "Go to the door",
            "targets": [{"object": "door"}],
            "start_poses": [{"x": 0.5, "y": 0.5}],
        }
    ],
}


def _variant(path: str, value: object) -> dict:
    """GOOD with one value replaced at a dotted path (list indices as digits)."""
    data = yaml.safe_load(yaml.safe_dump(GOOD))
    node = data
    *parents, last = path.split(".")
    for key in parents:
        node = node[int(key)] if key.isdigit() else node[key]
    node[int(last) if last.isdigit() else last] = value
    return data


# (case, YAML text, path the message must name, words of the problem it must contain)
BAD_FILES = [
    ("unknown_key", yaml.safe_dump(_variant("objects.0.colour", [1, 0, 0, 1])), "objects[0].colour", "extra"),
    ("wrong_type", yaml.safe_dump(_variant("bounds.x", "wide")), "bounds.x", "valid"),
    (
        "outside_bounds",
        yaml.safe_dump(_variant("objects.0.center", [7.0, 1.0])),
        "objects[0].center",
        "outside bounds",
    ),
    (
        "start_overlaps",
        yaml.safe_dump(_variant("tasks.0.start_poses.0", {"x": 2.1, "y": 1.8})),
        "tasks[0].start_poses[0]",
        "overlaps an obstacle",
    ),
    (
        "unknown_target",
        yaml.safe_dump(_variant("tasks.0.targets.0.object", "window")),
        "tasks[0].targets[0].object",
        "unknown target id 'window'",
    ),
    ("invalid_yaml", "name: tiny\nbounds: {x: [0, 4], y: [0, 4]\ntasks: []\n", "line ", "expected"),
]


def test_good_fixture_is_valid(tmp_path: Path) -> None:
    path = tmp_path / "tiny.yaml"
    path.write_text(yaml.safe_dump(GOOD))
    result = runner.invoke(app, ["scenarios", "show", str(path)])
    assert result.exit_code == 0, result.output
    assert "Go to the door" in result.stdout


@pytest.mark.parametrize(("case", "text", "where", "problem"), BAD_FILES, ids=[b[0] for b in BAD_FILES])
def test_bad_file_gives_one_line_and_exit_code_2(
    tmp_path: Path, case: str, text: str, where: str, problem: str
) -> None:
    path = tmp_path / f"{case}.yaml"
    path.write_text(text)
    result = runner.invoke(app, ["scenarios", "show", str(path)])
    assert result.exit_code == 2
    assert result.stdout == ""
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    line = lines[0]
    assert str(path) in line and where in line and problem.lower() in line.lower(), line
    assert "Traceback" not in result.output


def test_unknown_scenario_name_is_a_one_line_error() -> None:
    result = runner.invoke(app, ["scenarios", "show", "no_such_world"])
    assert result.exit_code == 2
    assert len(result.stderr.strip().splitlines()) == 1
    assert "no_such_world" in result.stderr and "factory" in result.stderr


def test_list_is_the_default_and_names_all_five() -> None:
    for args in (["scenarios"], ["scenarios", "list"]):
        result = runner.invoke(app, args)
        assert result.exit_code == 0, result.output
        for name in ("corridor_a", "corridor_b", "corridor_c", "factory", "maze_arena"):
            assert name in result.stdout
        assert "pr2" in result.stdout and "burger" in result.stdout


def test_show_factory_prints_tasks_and_writes_the_plot(tmp_path: Path) -> None:
    png = tmp_path / "out" / "factory.png"
    result = runner.invoke(app, ["scenarios", "show", "factory", "--plot", str(png)])
    assert result.exit_code == 0, result.output
    for task_id in [f"T{i}" for i in range(1, 11)]:
        assert task_id in result.stdout
    assert "Look for some stairs" in result.stdout and "rotate" in result.stdout
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20_000


def test_show_one_task(tmp_path: Path) -> None:
    result = runner.invoke(app, ["scenarios", "show", "corridor_b", "--task", "b5"])
    assert result.exit_code == 0, result.output
    assert "Go to the window" in result.stdout and "Go to room 101" not in result.stdout
    missing = runner.invoke(app, ["scenarios", "show", "corridor_b", "--task", "T99"])
    assert missing.exit_code == 2 and "T99" in missing.stderr
