"""The demo itself: `llmnav drive --task "Go to room 101"` — the hybrid planner with the real embedded model
(SmolLM2-135M through llama.cpp, grammar-constrained option choice)."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

from llmnav.runs.runlog import read_run
from llmnav.world.scenario import load_scenario


# Measured: 28-40 s on a quiet machine (model load ~1 s + two decisions of 12-18 s), 76 s at load average 5.
@pytest.mark.slow
def test_the_demo_reaches_room_101_with_the_real_local_model(tmp_path: Path) -> None:
    out = tmp_path / "demo"
    llmnav = Path(sys.executable).parent / "llmnav"  # the console script, exactly as `make demo` runs it
    done = subprocess.run(
        [str(llmnav), "drive", "--task", "Go to room 101", "--out", str(out), "--quiet"],
        capture_output=True,
        text=True,
        timeout=900,
        check=False,
    )
    record = read_run(out)
    summary = json.loads((out / "summary.json").read_text())
    assert record.complete and record.config["planner"] == "hybrid" and record.config["backend"] == "local"
    calls = record.of_type("llm_call")
    assert calls and all("reply" in c for c in calls), [c.get("error") for c in calls]
    # grammar-constrained decoding: every answer is a listed option, no correction turns needed
    assert [g["outcome"] for g in record.of_type("guard")] == ["ok"] * len(calls)
    assert all(c["purpose"] == "choice" and c["reply"]["latency_s"] > 0 for c in calls)
    # the tiny model picks option 1 and the menu puts the right thing first: room 101, then Finish
    assert done.returncode == 0, done.stderr[-2000:]
    assert summary["outcome"] == "completed" and summary["success"] and summary["iterations"] == 2
    x, y, yaw = record.poses()[-1]
    plate = load_scenario("corridor_a").object("R101")
    assert math.dist((x, y), plate.goal_point) < 0.5
    assert abs(math.remainder(math.atan2(plate.center[1] - y, plate.center[0] - x) - yaw, math.tau)) < 0.2
    assert summary["collisions"] == 0 and summary["json_errors"] == 0
