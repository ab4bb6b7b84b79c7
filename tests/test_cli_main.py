"""The console script itself (not CliRunner): usage errors are one line with exit 2, no traceback."""

from __future__ import annotations

import subprocess
import sys

import pytest

ENTRY = "from llmnav.cli import main; main()"


def llmnav(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-c", ENTRY, *args], capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize(
    "args",
    [
        ("drive", "--lidar-sectors", "abc"),
        ("drive", "--bogus"),
        ("score",),
        ("scenarios", "show", "nope"),
        ("drive", "--task-id", "M1", "--planner", "fsm", "--model-latency", "-5"),
        ("drive", "--task-id", "M1", "--planner", "fsm", "--ttl", "soon"),
        ("ablate", "--planner", "fsm", "--model-latency", "fast", "--dry-run"),
    ],
)
def test_bad_usage_is_one_line_and_exit_2(args):
    result = llmnav(*args)
    assert result.returncode == 2
    assert "Traceback" not in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1, result.stderr
    assert result.stderr.startswith("error:")


def test_help_exits_0():
    result = llmnav("--help")
    assert result.returncode == 0 and "drive" in result.stdout


def test_drive_refuses_to_overwrite_a_run(tmp_path):
    out = tmp_path / "run"
    first = llmnav("drive", "--scenario", "corridor_a", "--task-id", "A1", "--planner", "oracle", "--out", str(out))
    assert first.returncode == 0, first.stderr
    before = (out / "run.jsonl").read_bytes()
    second = llmnav("drive", "--scenario", "corridor_a", "--task-id", "A1", "--planner", "oracle", "--out", str(out))
    assert second.returncode == 2 and "already holds a run" in second.stderr
    assert (out / "run.jsonl").read_bytes() == before


def test_the_cli_and_the_planners_import_no_heavy_module() -> None:
    """`llmnav --help` starts without pydantic or numpy; a drive reaches its first request without plotting
    or scipy's import until a planner computes a distance transform (the figures come after the result)."""
    script = (
        "import sys, llmnav.cli\n"
        "print(*sorted(m for m in ('pydantic', 'yaml', 'numpy', 'scipy', 'matplotlib', 'pybullet', 'cv2')"
        " if m in sys.modules))\n"
        "import llmnav.runs.runner, llmnav.planners.observe, llmnav.sim.world\n"
        "import llmnav.planners.hybrid, llmnav.planners.fsm, llmnav.planners.stepwise\n"
        "import llmnav.planners.waypoints.planner\n"
        "import llmnav.baselines.frontier, llmnav.baselines.oracle\n"
        "print(*sorted(m for m in ('scipy', 'matplotlib', 'cv2', 'PIL') if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True).stdout
    assert out.splitlines() == ["", ""], out
