"""Prompt templates: every template renders completely, hashes are stable, errors name what is missing."""

from __future__ import annotations

import re
from itertools import product
from pathlib import Path

import pytest

from llmnav.errors import PromptTemplateError
from llmnav.planners import prompting

STEPWISE_VALUES = {"max_step_m": 5.0, "lidar_sectors": 8, "lidar_fov_deg": 90.0}

# Values the planners pass for each non-stepwise template.
OTHER_VALUES: dict[str, dict[str, object]] = {
    "self_check": {},
    "ground_system": {},
    "ground_user": {"command": "Go to room 101", "objects": "- room_101: room 101 at (3.0, 1.9)"},
    "waypoints_system": {
        "corridors": "- main: x from -1 to 14, y from -2 to 2",
        "junctions": "none",
        "robot_x": "0.00",
        "robot_y": "0.00",
        "robot_yaw_deg": "0",
        "target_name": "room 101",
        "target_x": "3.00",
        "target_y": "1.50",
        "margin": 0.5,
        "spacing": 0.7,
        "tolerance": 0.05,
        "max_waypoints": 3,
        "obstacles": "none",
    },
    "waypoints_user": {"target_name": "room 101", "max_waypoints": 3},
    "waypoints_feedback": {"problems": "- waypoint 2 (5.0, 1.9) is within 0.5 m of the corridor edge"},
    "fsm_velocity": {"v_min": 0.0, "v_max": 0.06, "w_max": 0.5, "d_goal": 0.5},
    "hybrid_system": {"robot": "pr2"},
    "hybrid_user": {
        "task": "Go to the pile of pellets",
        "last_result": "none yet",
        "observation": "Front distance: 3.2 m",
        "options": "1. go to pellets\n2. rotate 360 degrees",
    },
}

LEFTOVER = re.compile(r"\$\w|\$\{|<!--|-->")


def assert_complete(text: str) -> None:
    assert text.strip(), "empty prompt"
    assert not LEFTOVER.search(text), f"leftover placeholder or directive: {LEFTOVER.search(text)}"


def test_every_template_is_covered_by_this_test() -> None:
    assert set(prompting.list_templates()) == set(prompting.STEPWISE_VARIANTS) | set(OTHER_VALUES)


@pytest.mark.parametrize("name", prompting.stepwise_variants())
@pytest.mark.parametrize(("lidar", "image", "detections"), list(product([True, False], repeat=3)))
def test_stepwise_variants_render(name: str, lidar: bool, image: bool, detections: bool) -> None:
    text = prompting.render(name, lidar=lidar, image=image, detections=detections, **STEPWISE_VALUES)
    assert_complete(text)
    assert "```json" in text and '"command"' in text  # one fenced example
    for command in ("FRONT", "BACK", "ROTATE_LEFT", "ROTATE_RIGHT", "COMPLETE"):
        assert command in text
    assert "at most 5)" in text  # the max step is filled in


def test_variant_sections_follow_the_spec() -> None:
    flags = {"lidar": True, "image": True, "detections": False}
    full = prompting.render("full", **flags, **STEPWISE_VALUES)
    for heading in ("# Role", "# Commands", "# Movement constraints", "# Workflow", "# Camera image",
                    "# LiDAR data", "# Output format", "# Key priorities"):
        assert heading in full
    assert "# Movement constraints" not in prompting.render("full_noconstraints", **flags, **STEPWISE_VALUES)
    no_lidar = prompting.render("no_lidar_guidelines", **flags, **STEPWISE_VALUES)
    assert "# LiDAR data" not in no_lidar and "# Camera image" in no_lidar
    short = prompting.render("short", **flags, **STEPWISE_VALUES)
    assert "# Workflow" not in short and "# Movement constraints" in short and "# Output format" in short
    short_nc = prompting.render("short_noconstraints", **flags, **STEPWISE_VALUES)
    assert "# Movement constraints" not in short_nc and "# Commands" in short_nc
    # sensing flags switch the guideline sections
    no_image = prompting.render("full", lidar=True, image=False, detections=True, **STEPWISE_VALUES)
    assert "# Camera image" not in no_image and "# Detected objects" in no_image
    assert "8" in full and "90 degrees" in full


@pytest.mark.parametrize("name", sorted(OTHER_VALUES))
def test_other_templates_render(name: str) -> None:
    text = prompting.render(name, **OTHER_VALUES[name])
    assert_complete(text)
    for value in OTHER_VALUES[name].values():
        shown = f"{value:g}" if isinstance(value, float) else str(value)
        assert shown in text, f"{shown!r} missing from {name}"


def test_self_check_asks_for_confirmed() -> None:
    assert "CONFIRMED" in prompting.render("self_check")


def test_missing_placeholder_and_flag_are_named() -> None:
    values = dict(OTHER_VALUES["fsm_velocity"])
    del values["d_goal"]
    with pytest.raises(PromptTemplateError, match=r"'fsm_velocity'.*\$d_goal"):
        prompting.render("fsm_velocity", **values)
    with pytest.raises(PromptTemplateError, match="flag 'image'"):
        prompting.render("full", lidar=True, detections=False, **STEPWISE_VALUES)


@pytest.mark.parametrize("name", ["does_not_exist", "../pyproject", "parts/stepwise_role", ""])
def test_unknown_or_unsafe_names_are_rejected(name: str) -> None:
    with pytest.raises(PromptTemplateError):
        prompting.render(name)


def test_extra_values_are_ignored() -> None:
    assert prompting.render("ground_system", unused="x") == prompting.render("ground_system")


def test_aliases() -> None:
    flags = {"lidar": True, "image": True, "detections": False, **STEPWISE_VALUES}
    assert prompting.render("self-check", **flags) == prompting.render("full", **flags)
    assert prompting.render("full-noconstraints", **flags) == prompting.render("full_noconstraints", **flags)


def test_hashes_are_stable_and_distinct() -> None:
    names = prompting.list_templates()
    first = {n: prompting.template_hash(n) for n in names}
    assert first == {n: prompting.template_hash(n) for n in names}
    assert all(re.fullmatch(r"[0-9a-f]{64}", h) for h in first.values())
    assert len(set(first.values())) == len(names)


def test_hash_covers_included_parts(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "parts").mkdir()
    (tmp_path / "t.md").write_text("<!-- include p -->\nHello $who\n", encoding="utf-8")
    (tmp_path / "parts" / "p.md").write_text("Part one.\n", encoding="utf-8")
    monkeypatch.setattr(prompting, "prompt_dir", lambda: tmp_path)
    before = prompting.template_hash("t")
    assert prompting.render("t", who="robot") == "Part one.\nHello robot\n"
    (tmp_path / "parts" / "p.md").write_text("Part two.\n", encoding="utf-8")
    assert prompting.template_hash("t") != before


def test_load_template_returns_template() -> None:
    template = prompting.load_template("waypoints_user")
    assert template.substitute(target_name="window", max_waypoints=3).count("window") == 1


SPELLINGS = ["self_check", "self_check_variant", "full-noconstraints", "Full", "waypoints_system"]


@pytest.mark.parametrize("spelling", SPELLINGS)
def test_stepwise_prompt_has_one_name_per_variant(spelling: str) -> None:
    """Another spelling of a variant is refused with the names, at the CLI: one line, exit 2, no run folder."""
    from typer.testing import CliRunner

    from llmnav.cli import app

    res = CliRunner().invoke(app, ["drive", "--planner", "stepwise", "--task-id", "T1", "--prompt", spelling,
                                   "--backend", "policy:first", "--out", "/nonexistent/never"])  # fmt: skip
    assert res.exit_code == 2, res.output
    lines = [line for line in res.output.splitlines() if line.strip()]
    assert len(lines) == 1 and f"unknown prompt variant '{spelling}'" in lines[0]
    assert ", ".join(prompting.stepwise_variants()) in lines[0]


def test_every_variant_name_is_accepted() -> None:
    from llmnav.planners.base import drive_options

    for name in prompting.stepwise_variants():
        assert drive_options("stepwise", prompt=name).prompt == name  # type: ignore[attr-defined]


def test_a_package_ships_its_own_prompts(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Templates are read from the named package's prompts/ folder, includes and hashes included."""
    folder = tmp_path / "shipsprompts" / "prompts"
    (folder / "parts").mkdir(parents=True)
    (tmp_path / "shipsprompts" / "__init__.py").write_text("", encoding="utf-8")
    (folder / "greet.md").write_text("<!-- include who -->\nGo to $place.\n", encoding="utf-8")
    (folder / "parts" / "who.md").write_text("You are a robot.\n", encoding="utf-8")
    monkeypatch.syspath_prepend(str(tmp_path))
    assert prompting.list_templates("shipsprompts") == ["greet"]
    assert prompting.render("greet", "shipsprompts", place="the door") == "You are a robot.\nGo to the door.\n"
    before = prompting.template_hash("greet", "shipsprompts")
    (folder / "parts" / "who.md").write_text("You are a rover.\n", encoding="utf-8")
    assert prompting.template_hash("greet", "shipsprompts") != before
    # the bundled folder is not searched for a package's names, nor the package for bundled ones
    with pytest.raises(PromptTemplateError, match="unknown prompt template 'full' .*known templates: greet"):
        prompting.render("full", "shipsprompts")
    with pytest.raises(PromptTemplateError, match="unknown prompt template 'greet'"):
        prompting.render("greet")


def test_a_package_without_prompts_is_one_clear_error(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "noprompts").mkdir()
    (tmp_path / "noprompts" / "__init__.py").write_text("", encoding="utf-8")
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(PromptTemplateError, match="package 'noprompts' has no prompts/ folder"):
        prompting.render("x", "noprompts")
    with pytest.raises(PromptTemplateError, match="cannot read the prompts of package 'nosuchpackage_xyz'"):
        prompting.render("x", "nosuchpackage_xyz")


def test_a_zipped_package_ships_its_prompts_too(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Read through importlib.resources, not the file system: a plug-in imported from a zip works alike."""
    import zipfile

    archive = tmp_path / "zipped.zip"
    with zipfile.ZipFile(archive, "w") as zipped:
        zipped.writestr("zippedprompts/__init__.py", "")
        zipped.writestr("zippedprompts/prompts/hello.md", "<!-- include part -->\nHello $who\n")
        zipped.writestr("zippedprompts/prompts/parts/part.md", "From a zip.\n")
    monkeypatch.syspath_prepend(str(archive))
    assert prompting.list_templates("zippedprompts") == ["hello"]
    assert prompting.render("hello", "zippedprompts", who="robot") == "From a zip.\nHello robot\n"
