"""`scenarios check`: broken promises are found, one line each; malformed and hostile files never crash it."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from llmnav.buildings.check import check_file
from llmnav.cli import app

# A 10 m x 6 m room split at x = 5 by a wall with a 1.4 m doorway at its north end; a tall cabinet on the east
# side, a crate walled in on three sides by the south-east corner and a low screen.
ROOM: dict[str, object] = {
    "name": "check-room",
    "robot": "pr2",
    "bounds": {"x": [0.0, 10.0], "y": [0.0, 6.0]},
    "walls": [
        {"id": "south", "center": [5.0, 0.05], "size": [10.0, 0.1]},
        {"id": "north", "center": [5.0, 5.95], "size": [10.0, 0.1]},
        {"id": "west", "center": [0.05, 3.0], "size": [0.1, 6.0]},
        {"id": "east", "center": [9.95, 3.0], "size": [0.1, 6.0]},
        {"id": "divider", "center": [5.0, 2.25], "size": [0.1, 4.5]},  # doorway y 4.5..5.9
    ],
    "objects": [
        {"id": "cabinet", "label": "cabinet", "center": [8.0, 2.0], "size": [0.6, 0.6], "height": 2.0},
    ],
    "tasks": [
        {
            "id": "ok",
            "text": "Go to the cabinet",
            "targets": [{"object": "cabinet"}],
            "start_poses": [{"x": 2.0, "y": 2.0, "yaw_deg": 0}],  # behind the divider
        }
    ],
    "default_start": {"x": 2.0, "y": 2.0},
}


def _write(tmp_path: Path, data: object, name: str = "s.yaml") -> Path:
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data, sort_keys=False) if not isinstance(data, str) else data, encoding="utf-8")
    return path


def _with_task(**changes: object) -> dict[str, object]:
    task = {**ROOM["tasks"][0], **changes}  # type: ignore[index]
    return {**ROOM, "tasks": [task]}


def invoke(*args: str) -> tuple[int, str]:
    result = CliRunner().invoke(app, list(args))
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    return result.exit_code, result.output


def test_a_sound_file_passes(tmp_path: Path) -> None:
    path = _write(tmp_path, ROOM)
    assert check_file(path) == []
    code, output = invoke("scenarios", "check", str(path))
    assert code == 0 and output.strip() == f"{path}: ok"


def test_a_start_too_close_to_a_wall_is_reported(tmp_path: Path) -> None:
    # 0.4 m from the divider: more than the PR2's radius (0.36 m), less than radius + grid margin (0.46 m).
    path = _write(tmp_path, _with_task(start_poses=[{"x": 4.55, "y": 2.0}]))
    (line,) = check_file(path)
    assert "start 1" in line and "0.40 m from the nearest wall or object" in line and "needs 0.46 m" in line


def test_a_target_walled_in_is_unreachable(tmp_path: Path) -> None:
    data = _with_task()
    # A ring of walls around the cabinet, 1.6 m out: the approach band (1.6-2.4 m) is outside the ring,
    # so close it with a second ring at 2.6 m; nothing between them is reachable from the start.
    walls = list(data["walls"])  # type: ignore[call-overload]
    for half, name in ((1.2, "inner"), (2.7, "outer")):
        walls += [
            {"id": f"{name}-s", "center": [8.0, 2.0 - half], "size": [2 * half, 0.1]},
            {"id": f"{name}-n", "center": [8.0, 2.0 + half], "size": [2 * half, 0.1]},
            {"id": f"{name}-w", "center": [8.0 - half, 2.0], "size": [0.1, 2 * half]},
            {"id": f"{name}-e", "center": [8.0 + half, 2.0], "size": [0.1, 2 * half]},
        ]
    data["walls"] = walls
    data["bounds"] = {"x": [0.0, 12.0], "y": [-2.0, 6.0]}
    lines = check_file(_write(tmp_path, data))
    assert len(lines) == 1 and "no target can be reached by the pr2 (radius 0.36 m)" in lines[0], lines


def test_a_target_in_view_is_reported_and_one_behind_the_start_is_not(tmp_path: Path) -> None:
    # 3.47 m from the cabinet at (8, 2), which lies 46 deg to the right of east.
    facing = _with_task(start_poses=[{"x": 5.6, "y": 4.5, "yaw_deg": -45}])
    (line,) = check_file(_write(tmp_path, facing, "facing.yaml"))
    assert "target 'cabinet' is in the camera's view" in line
    away = _with_task(start_poses=[{"x": 5.6, "y": 4.5, "yaw_deg": 135}])
    assert check_file(_write(tmp_path, away, "away.yaml")) == []


def test_every_problem_gets_its_own_line_and_exit_2(tmp_path: Path) -> None:
    bad = _with_task(start_poses=[{"x": 4.55, "y": 2.0}, {"x": 5.6, "y": 4.5, "yaw_deg": -45}, {"x": 2.0, "y": 2.0}])
    path = _write(tmp_path, bad)
    code, output = invoke("scenarios", "check", str(path))
    lines = output.strip().splitlines()
    assert code == 2
    assert len(lines) == 2 and "start 1" in lines[0] and "start 2" in lines[1], output


def _billion_laughs() -> str:
    lines = ['a0: &a0 ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    for k in range(1, 10):
        refs = ", ".join([f"*a{k - 1}"] * 9)
        lines.append(f"a{k}: &a{k} [{refs}]")
    return "\n".join(lines) + "\nname: x\nbounds: {x: [0, 1], y: [0, 1]}\n"


HOSTILE: list[tuple[str, str, str]] = [
    ("empty", "", "expected a mapping"),
    ("a list", "- 1\n- 2\n", "expected a mapping"),
    ("bad yaml", "name: [unclosed\n", "line"),
    ("billion laughs", _billion_laughs(), "aliases"),
    ("deep nesting", "a: " + "[" * 100 + "]" * 100 + "\n", "nested deeper than 32"),
    ("deeper than the parser takes", "a: " + "[" * 5000 + "]" * 5000 + "\n", "nesting depth"),
    ("not a number", "name: x\nbounds: {x: [0, big], y: [0, 1]}\n", "bounds.x[1]"),
    ("nan", "name: x\nbounds: {x: [0, .nan], y: [0, 1]}\n", "finite"),
    ("binary", "\x00\x01\x02\xff name", "control characters are not allowed"),
]


@pytest.mark.parametrize(("case", "text", "needle"), HOSTILE, ids=[c[0] for c in HOSTILE])
def test_malformed_and_hostile_files_give_lines_and_exit_2(tmp_path: Path, case: str, text: str, needle: str) -> None:
    path = tmp_path / "bad.yaml"
    path.write_bytes(text.encode("utf-8", errors="surrogateescape"))
    code, output = invoke("scenarios", "check", str(path))
    assert code == 2, output
    assert "Traceback" not in output
    lines = output.strip().splitlines()
    assert lines and all(line.startswith(str(path)) or line.startswith("error:") for line in lines), output
    assert needle in output, output


def test_several_field_errors_are_listed_one_a_line(tmp_path: Path) -> None:
    data = {**ROOM, "robot": "tank", "wall_height": -1, "colour": "red"}
    code, output = invoke("scenarios", "check", str(_write(tmp_path, data)))
    lines = output.strip().splitlines()
    assert code == 2
    assert len(lines) == 3, output
    assert any("robot" in line for line in lines) and any("wall_height" in line for line in lines)
    assert any("colour" in line for line in lines)


def test_a_world_too_large_to_rasterise_is_refused_before_building_a_grid(tmp_path: Path) -> None:
    data = {**ROOM, "bounds": {"x": [0.0, 1e6], "y": [0.0, 1e6]}}
    (line,) = check_file(_write(tmp_path, data))  # the scenario's own size limit refuses it, in one line
    assert "bounds" in line and "1000" in line


def test_missing_files_and_fifos_are_lines_too(tmp_path: Path) -> None:
    fifo = tmp_path / "pipe.yaml"
    os.mkfifo(fifo)
    for path in (tmp_path / "missing.yaml", fifo):
        code, output = invoke("scenarios", "check", str(path))
        assert code == 2 and len(output.strip().splitlines()) == 1 and "Traceback" not in output, output


def test_a_start_within_the_success_radius_is_reported(tmp_path: Path) -> None:
    # Facing away from the cabinet at (8, 2), 2.47 m from it: inside 2.5 m + 0.5 m.
    path = _write(tmp_path, _with_task(start_poses=[{"x": 5.6, "y": 2.6, "yaw_deg": 180}]))
    (line,) = check_file(path)
    assert "target 'cabinet' is 2.47 m away: the task begins within 2.5 m + 0.5 m" in line


def test_bundled_worlds_with_hidden_targets_pass_but_one_start_in_reach_of_the_fire() -> None:
    root = Path(__file__).parents[2] / "scenarios"
    assert check_file(root / "maze_arena.yaml") == []
    # T10 start 5 (3.5, -8.5) is 1.70 m from the fire at (5.2, -8.4): the task begins solved.
    (line,) = check_file(root / "factory.yaml")
    assert "(T10 start 5 at 3.5, -8.5): target 'FIRE' is 1.70 m away" in line
