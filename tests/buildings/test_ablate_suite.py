"""`llmnav ablate --scenario generated:KIND:N` and `--scenario FOLDER`: one resumable ablation per building."""

from __future__ import annotations

import json
from pathlib import Path

from typer.testing import CliRunner

from llmnav.buildings.generate import Request, generate
from llmnav.cli import app


def invoke(*args: str) -> tuple[int, str]:
    result = CliRunner().invoke(app, list(args))
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    return result.exit_code, result.output


ORACLE = ["--planner", "oracle", "--tasks", "T1", "--poses", "1"]


def _run_folders(root: Path) -> set[str]:
    return {p.relative_to(root).as_posix() for p in root.glob("*/*") if p.is_dir()}


def test_a_generated_suite_runs_each_building_and_resumes(tmp_path: Path) -> None:
    root = tmp_path / "sweep"
    code, output = invoke("ablate", "--scenario", "generated:flat:2:40", *ORACLE, "--out", str(root))
    assert code == 0, output
    assert "suite of 2 scenarios: 2/2 episodes done" in output
    for seed in (40, 41):
        written = root / "scenarios" / f"flat-{seed}.yaml"
        assert written.read_text(encoding="utf-8") == generate(Request("flat", seed)).text
        manifest = json.loads((root / f"flat-{seed}" / "manifest.json").read_text(encoding="utf-8"))
        assert manifest["grid"]["scenario"] == str(written)
    folders = _run_folders(root)
    # Again: the same bytes are found, every episode is kept, no run folder is added.
    code, output = invoke("ablate", "--scenario", "generated:flat:2:40", *ORACLE, "--out", str(root))
    assert code == 0 and "2/2 episodes done" in output, output
    assert _run_folders(root) == folders


def test_an_edited_generated_file_is_refused_not_overwritten(tmp_path: Path) -> None:
    root = tmp_path / "sweep"
    (root / "scenarios").mkdir(parents=True)
    edited = root / "scenarios" / "flat-0.yaml"
    edited.write_text("name: mine\n", encoding="utf-8")
    code, output = invoke("ablate", "--scenario", "generated:flat:1", *ORACLE, "--out", str(root))
    assert code == 2 and "differs from the building its seed gives" in output, output
    assert edited.read_text(encoding="utf-8") == "name: mine\n"


def test_a_folder_of_scenarios_is_a_suite(tmp_path: Path) -> None:
    folder = tmp_path / "suite"
    folder.mkdir()
    for seed in (3, 4):
        (folder / f"office-{seed}.yaml").write_text(generate(Request("office", seed)).text, encoding="utf-8")
    code, output = invoke("ablate", "--scenario", str(folder), *ORACLE, "--out", str(tmp_path / "sweep"), "--dry-run")
    assert code == 0, output
    assert (tmp_path / "sweep").exists() is False  # a dry run writes nothing for a folder suite
    assert output.count("1 episodes (planner") == 2 and "office-3" in output and "office-4" in output, output


def test_bad_suite_names_are_one_line(tmp_path: Path) -> None:
    for spec, needle in (
        ("generated:castle:2", "unknown building kind"),
        ("generated:flat", "expected generated:KIND:N"),
        ("generated:flat:0", "1 to 1000"),
    ):
        code, output = invoke("ablate", "--scenario", spec, *ORACLE, "--out", str(tmp_path / "x"))
        assert code == 2 and len(output.strip().splitlines()) == 1 and needle in output, output
    empty = tmp_path / "empty"
    empty.mkdir()
    code, output = invoke("ablate", "--scenario", str(empty), *ORACLE, "--out", str(tmp_path / "x"))
    assert code == 2 and "without scenario files" in output, output
