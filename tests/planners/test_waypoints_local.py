"""`llmnav plan` with the real embedded model (SmolLM2-135M through llama.cpp, WaypointList grammar): the
pipeline runs whatever the tiny model writes — every attempt parses, is validated, and each verdict names
exactly the problems the validator finds in those points."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from llmnav.mapping.grid import build_grid
from llmnav.planners.waypoints.planner import validate_waypoints
from llmnav.world.scenario import load_scenario


# Not marked slow: measured 15-22 s on 2 cores at load average 5 (model load + one generation: at temperature 0
# the model answers this prompt with a valid plan at once). Each extra generation costs about 5-10 s.
def test_plan_with_the_real_local_model(tmp_path: Path) -> None:
    from llmnav.cli import app

    figure = tmp_path / "plan.png"
    res = CliRunner().invoke(
        app,
        [
            "plan",
            "--task",
            "Go to room 105",
            "--backend",
            "local",
            "--max-generations",
            "3",
            "--plot",
            str(figure),
            "--json",
        ],
    )
    assert res.exit_code in (0, 1), res.output  # 1: no valid plan in 3 generations, still a clean end
    data = json.loads(res.stdout)
    attempts = data["attempts"]
    assert 1 <= len(attempts) <= 3 and data["target"] == "R105"
    valid = [a["valid"] for a in attempts]
    assert data["wgsr"] == pytest.approx(100.0 * sum(valid) / len(attempts))
    assert (res.exit_code == 0) == any(valid) and (data["waypoints"] is not None) == any(valid)
    assert valid[:-1] == [False] * (len(attempts) - 1)  # regeneration stops at the first valid plan
    assert data["planning_time_s"] > 0 and figure.stat().st_size > 10_000

    scenario = load_scenario("corridor_a")
    grid = build_grid(scenario)
    for attempt in attempts:
        # grammar-constrained decoding: always a parsable array of at most max_waypoints points
        assert attempt["points"] and len(attempt["points"]) <= scenario.waypoint_rules.max_waypoints
        points = [(float(x), float(y)) for x, y in attempt["points"]]
        expected = validate_waypoints(points, (0.0, 0.0), (6.5, 1.1), scenario, grid, scenario.waypoint_rules)
        assert attempt["problems"] == expected and attempt["valid"] == (not expected)
