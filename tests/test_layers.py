"""The import-linter contracts in pyproject.toml hold (the default suite runs them, so CI does too)."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).parents[1]


def lint_imports() -> str:
    found = shutil.which("lint-imports", path=str(Path(sys.executable).parent))
    if found is None:
        pytest.fail("lint-imports is missing: install the lint extra (pip install -e '.[lint]')")
    return found


def test_every_import_contract_is_kept() -> None:
    done = subprocess.run([lint_imports(), "--no-cache"], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-2000:]
    assert "3 kept, 0 broken" in done.stdout


def test_an_upward_import_breaks_the_contract(tmp_path: Path) -> None:
    # The checker can fail: the same contracts on a copy of the package where the chat leaf imports a planner.
    package = tmp_path / "llmnav"
    shutil.copytree(ROOT / "llmnav", package, ignore=shutil.ignore_patterns("__pycache__", "_data"))
    chat = package / "core" / "chat.py"
    chat.write_text(chat.read_text() + "\nimport llmnav.planners.stepwise  # noqa: E402,F401\n")
    shutil.copy(ROOT / "pyproject.toml", tmp_path / "pyproject.toml")
    done = subprocess.run(
        [lint_imports(), "--no-cache"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
        env={"PYTHONPATH": str(tmp_path), "PATH": ""},
    )
    assert done.returncode != 0
    assert "llmnav.core.chat is not allowed to import llmnav.planners" in done.stdout


def test_the_architecture_page_lists_the_layers_the_contract_enforces() -> None:
    import re
    import tomllib

    contract = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]["contracts"][0]
    page = (ROOT / "docs" / "architecture.md").read_text()
    listed = re.search(r"```text\n(llmnav\.cli\n.*?)```", page, re.S)
    assert listed is not None, "docs/architecture.md has no layer list"
    assert listed.group(1).splitlines() == contract["layers"]
