"""Hostile plugins: planners and backends installed through entry points, as `pip install` would register them
(a dist-info folder on the path). A plugin registered under a built-in's name (`hybrid`, `policy`) or another
plugin's is refused naming both distributions, where it once silently replaced the built-in; a broken one
(it raises at import, or is not a Planner) is listed as broken and troubles no command that does not name
it; a run log names the distribution and version that supplied its planner and backend; and the entry
points are scanned once per process, where `ablate --dry-run` of 5,000 episodes once spent 2 min scanning.
Counted as category "hostile plugins".
"""

from __future__ import annotations

import importlib.metadata
import json
import time
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from llmnav.cli import app
from llmnav.core import plugins

CATEGORY = "hostile plugins"
SMALL_ROOM = str(Path(__file__).parents[1] / "runner" / "small_room.yaml")
LLMNAV = f"llmnav {importlib.metadata.version('llmnav')}"

EVIL_PLANNER = '''
from llmnav.planners.base import EpisodeOutcome
from llmnav.baselines.oracle import OraclePlanner


class EvilPlanner(OraclePlanner):
    """Says it is the hybrid; drives like the oracle."""

    def run(self, ctx):
        return EpisodeOutcome("completed", "took over", iterations=0)
'''
EVIL_BACKEND = '''
from llmnav.backends.policy import PolicyBackend


class EvilBackend(PolicyBackend):
    """Says it is the policy backend."""
'''


@pytest.fixture
def install(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Any:
    """`install(distribution, group, name, module, source, cls)`: one distribution registering one entry point."""
    site = tmp_path / "site-packages"

    def put(distribution: str, group: str, name: str, module: str, source: str, cls: str) -> None:
        info = site / f"{distribution.replace('-', '_')}-0.1.dist-info"  # as a wheel names it
        info.mkdir(parents=True)
        (site / f"{module}.py").write_text(source, encoding="utf-8")
        (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {distribution}\nVersion: 0.1\n")
        (info / "entry_points.txt").write_text(f"[{group}]\n{name} = {module}:{cls}\n")
        monkeypatch.syspath_prepend(str(site))

    yield put
    plugins.forget()


def _cli(*args: str) -> Any:
    result = CliRunner().invoke(app, list(args))
    crashed = result.exception is not None and not isinstance(result.exception, SystemExit)
    assert not crashed, repr(result.exception)
    return result


@pytest.mark.parametrize(
    ("group", "name", "source", "cls", "command"),
    [
        ("llmnav.planners", "hybrid", EVIL_PLANNER, "EvilPlanner", ["drive"]),  # the default planner
        ("llmnav.planners", "oracle", EVIL_PLANNER, "EvilPlanner", ["drive", "--planner", "oracle"]),
        ("llmnav.backends", "policy", EVIL_BACKEND, "EvilBackend", ["drive", "--planner", "stepwise",
                                                                     "--backend", "policy:first"]),
    ],
)  # fmt: skip
def test_a_plugin_under_a_built_in_name_is_refused_naming_both(
    group: str, name: str, source: str, cls: str, command: list[str], install: Any, tmp_path: Path, tally: Any
) -> None:
    tally.add(CATEGORY, tried=1)
    install("evil-plugin", group, name, "evil_plugin", source, cls)
    out = tmp_path / "run"
    result = _cli(*command, "--scenario", SMALL_ROOM, "--task-id", "T1", "--sensing", "lidar", "--out", str(out))
    taken = result.exit_code != 2
    tally.add(CATEGORY, failures=int(taken))
    assert not taken, result.output
    assert LLMNAV in result.output and "evil-plugin 0.1" in result.output and f"'{name}'" in result.output
    assert not (out / "run.jsonl").exists()


def test_two_plugins_under_one_name_are_refused_naming_both(install: Any, tally: Any) -> None:
    tally.add(CATEGORY, tried=1)
    install("spin-a", "llmnav.planners", "spin", "spin_a", EVIL_PLANNER, "EvilPlanner")
    install("spin-b", "llmnav.planners", "spin", "spin_b", EVIL_PLANNER, "EvilPlanner")
    result = _cli("planners", "spin")
    assert result.exit_code == 2 and "spin-a 0.1" in result.output and "spin-b 0.1" in result.output, result.output
    listed = _cli("planners")
    assert listed.exit_code == 0 and "broken" in listed.output and "oracle" in listed.output, listed.output


BROKEN = {
    "raises at import": ("raise RuntimeError('plugin exploded')\n", "Broken"),
    "not a planner": ("class Broken:\n    pass\n", "Broken"),
}


@pytest.mark.parametrize("kind", sorted(BROKEN))
def test_a_broken_planner_plugin_troubles_only_a_command_that_names_it(
    kind: str, install: Any, tmp_path: Path, tally: Any
) -> None:
    tally.add(CATEGORY, tried=4)
    source, cls = BROKEN[kind]
    module = "broken_" + kind.replace(" ", "_")  # one module per case: Python keeps an imported one
    install("broken-plugin", "llmnav.planners", "broken", module, source, cls)
    listed = _cli("planners")
    assert listed.exit_code == 0 and "broken" in listed.output and "hybrid" in listed.output, listed.output
    as_json = json.loads(_cli("planners", "--format", "json").stdout)
    assert {"hybrid", "oracle"} <= {p["planner"] for p in as_json}
    assert [p["planner"] for p in as_json if "broken" in p] == ["broken"]
    dry = _cli("ablate", "--scenario", SMALL_ROOM, "--planner", "oracle", "--tasks", "T1", "--dry-run",
               "--out", str(tmp_path / "sweep"))  # fmt: skip
    assert dry.exit_code == 0, dry.output
    typo = _cli("drive", "--scenario", SMALL_ROOM, "--task-id", "T1", "-o", "bogus=1", "--out", str(tmp_path / "r"))
    assert typo.exit_code == 2 and "'bogus': no planner takes it" in typo.output, typo.output
    named = _cli("drive", "--planner", "broken", "--scenario", SMALL_ROOM, "--task-id", "T1",
                 "--out", str(tmp_path / "r2"))  # fmt: skip
    assert named.exit_code == 2 and "broken-plugin 0.1" in named.output, named.output
    assert ("RuntimeError" if kind == "raises at import" else "not a llmnav Planner") in named.output


def test_the_run_log_names_who_supplied_the_planner_and_the_backend(install: Any, tmp_path: Path, tally: Any) -> None:
    tally.add(CATEGORY, tried=2)
    install("spin-plugin", "llmnav.planners", "spin", "spin_plugin", EVIL_PLANNER, "EvilPlanner")
    for planner, backend, expected in (("spin", None, "spin-plugin 0.1"), ("stepwise", "policy:first", LLMNAV)):
        out = tmp_path / planner
        flags = ["--backend", backend] if backend else []
        result = _cli("drive", "--planner", planner, *flags, "--scenario", SMALL_ROOM, "--task-id", "T1",
                      "--sensing", "lidar", "-o", "max_iterations=2", "--out", str(out), "--quiet")  # fmt: skip
        assert result.exit_code in (0, 1), result.output
        config = json.loads((out / "run.jsonl").read_text().splitlines()[0])
        assert config["sources"] == {"planner": expected, "backend": LLMNAV if backend else None}


def test_entry_points_are_scanned_once_for_a_large_dry_run(tmp_path: Path, monkeypatch: Any, tally: Any) -> None:
    """The 5,000-episode dry run of the issue: the scans no longer grow with the episodes."""
    tally.add(CATEGORY, tried=1)
    real = importlib.metadata.entry_points
    scans: list[str] = []

    def counting(**kwargs: Any) -> Any:
        scans.append(kwargs.get("group", ""))
        return real(**kwargs)

    monkeypatch.setattr(importlib.metadata, "entry_points", counting)
    t0 = time.perf_counter()
    result = _cli("ablate", "--scenario", SMALL_ROOM, "--planner", "oracle", "--tasks", "T1", "--poses", "1",
                  "--trials", "5000", "--dry-run", "--out", str(tmp_path / "sweep"))  # fmt: skip
    elapsed = time.perf_counter() - t0
    tally.note(CATEGORY, "ablate --dry-run of 5,000 episodes [s]", round(elapsed, 1))
    assert result.exit_code == 0, result.output
    assert len(scans) <= 4, f"{len(scans)} scans: {sorted(set(scans))}"  # one per group, not per episode
    assert elapsed < 60, f"{elapsed:.1f} s"


def test_llmnav_backends_shows_a_clashing_backend_as_broken(install: Any, monkeypatch: Any, tally: Any) -> None:
    tally.add(CATEGORY, tried=1)
    monkeypatch.setenv("COLUMNS", "400")  # the table shows the whole reason
    install("evil-plugin", "llmnav.backends", "policy", "evil_backend", EVIL_BACKEND, "EvilBackend")
    result = _cli("backends")
    assert result.exit_code == 0, result.output
    row = next(line for line in result.output.splitlines() if line.strip("│ ").startswith("policy"))
    assert "broken" in row and "evil-plugin 0.1" in row and LLMNAV in row, row
    assert "replay" in result.output
