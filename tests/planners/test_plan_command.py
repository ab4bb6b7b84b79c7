"""`llmnav plan` through the CLI with scripted answers: attempts and verdicts, planning time and WGSR, the
plan figure, `--json`, exit codes, `--execute`, and bad input."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from llmnav.backends.replay import write_script
from llmnav.cli import app
from llmnav.commands import common
from llmnav.core.resources import resource_dir
from llmnav.runs.runlog import read_run

runner = CliRunner()
BAD = [(3.0, 1.7), (3.2, 1.4), (6.5, 0.5)]  # outside the margin, too close, off target
GOOD = [(3.0, 0.5), (6.5, 1.1)]
PROBLEMS = [
    "waypoint 1 (3.00, 1.70) is outside every corridor with the 0.5 m margin",
    "waypoint 2 (3.20, 1.40) is 0.36 m from the previous point; keep at least 0.7 m",
    "the final waypoint is 0.60 m from the target (6.50, 1.10); it must be within 0.05 m",
]


@pytest.fixture(autouse=True)
def wide_console(monkeypatch: pytest.MonkeyPatch) -> None:
    """A wide console, so table cells do not wrap inside the phrases checked."""
    monkeypatch.setattr(common.console, "_width", 240)


def plan_text(points: list[tuple[float, float]]) -> str:
    return json.dumps([{"x": x, "y": y} for x, y in points])


def replay(path: Path, replies: list[str]) -> str:
    """A replay backend spec answering `replies` in order, whatever is asked."""
    return "replay:" + write_script(path, replies, purpose="waypoints")


def test_plan_prints_every_verdict_and_writes_the_figure(tmp_path: Path) -> None:
    figure = tmp_path / "plan.png"
    backend = replay(tmp_path / "script", [plan_text(BAD), plan_text(GOOD)])
    res = runner.invoke(app, ["plan", "--task", "Go to room 105", "--backend", backend, "--plot", str(figure)])
    assert res.exit_code == 0, res.output
    out = res.output
    assert "target R105 in corridor_a" in out
    for problem in PROBLEMS:
        assert problem in out
    assert "(3.00, 0.50) → (6.50, 1.10)" in out and "valid" in out
    assert "WGSR 50.0 %" in out and f"plot {figure}" in out
    seconds = float(out.split("planning time ")[1].split(" s")[0])
    assert 0.5 <= seconds < 0.9  # two scripted replies of 0.25 s plus our own work

    # a real figure: a PNG of sensible size with the blue plan and the red target drawn
    import matplotlib.image as mpimg

    assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and figure.stat().st_size > 20_000
    pixels = mpimg.imread(figure)[..., :3]
    assert pixels.shape[0] > 300 and pixels.shape[1] > 600
    blue = (np.abs(pixels - np.array([0.12, 0.47, 0.71])) < 0.08).all(axis=-1).sum()  # tab:blue
    red = (np.abs(pixels - np.array([0.84, 0.15, 0.16])) < 0.08).all(axis=-1).sum()  # tab:red
    assert blue > 200 and red > 50


def test_plan_json_output_parses(tmp_path: Path) -> None:
    backend = replay(tmp_path / "script", [plan_text(BAD), plan_text(GOOD)])
    res = runner.invoke(
        app,
        ["plan", "--task", "Go to room 105", "--backend", backend, "--plot", str(tmp_path / "p.png"), "--json"],
    )
    assert res.exit_code == 0, res.output
    data = json.loads(res.stdout)
    assert data["target"] == "R105" and data["target_point"] == [6.5, 1.1]
    assert data["waypoints"] == [list(p) for p in GOOD] and data["wgsr"] == 50.0
    assert [(a["number"], a["valid"]) for a in data["attempts"]] == [(1, False), (2, True)]
    assert data["attempts"][0]["problems"] == PROBLEMS and data["attempts"][1]["problems"] == []
    assert data["planning_time_s"] >= 0.5
    assert (tmp_path / "p.png").exists()


def test_no_valid_plan_exits_1_after_max_generations(tmp_path: Path) -> None:
    backend = replay(tmp_path / "script", [plan_text(BAD), "no idea", plan_text(GOOD)])
    res = runner.invoke(
        app,
        [
            "plan",
            "--task",
            "Go to room 105",
            "--backend",
            backend,
            "--max-generations",
            "2",
            "--plot",
            str(tmp_path / "p.png"),
        ],
    )
    assert res.exit_code == 1, res.output
    assert "WGSR 0.0 %" in res.output and PROBLEMS[0] in res.output
    assert "parse: " in res.output  # the prose answer's verdict
    assert (tmp_path / "p.png").exists()  # the figure shows the rejected attempts too


def test_execute_drives_the_plan(tmp_path: Path) -> None:
    backend = replay(tmp_path / "script", [plan_text(BAD), plan_text(GOOD)])  # nothing left to ask later
    out = tmp_path / "run"
    res = runner.invoke(
        app,
        [
            "plan",
            "--task",
            "Go to room 105",
            "--backend",
            backend,
            "--plot",
            str(tmp_path / "p.png"),
            "--execute",
            "--out",
            str(out),
        ],
    )
    assert res.exit_code == 0, res.output
    assert "completed" in res.output and str(out) in res.output
    record = read_run(out)
    assert record.config["planner"] == "waypoints"
    assert record.config["options"]["preset_waypoints"] == [list(p) for p in GOOD]
    assert record.of_type("llm_call") == []  # the plan was made already: no model call while driving
    assert [a["parameters"] for a in record.of_type("action")] == [list(p) for p in GOOD]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["outcome"] == "completed" and summary["distance_m"] <= 0.11


def test_execute_an_ambiguous_target_from_a_scenario_file(tmp_path: Path) -> None:
    # a scenario given by path whose name no bundled scenario has: the run must load the same file
    text = (resource_dir("scenarios") / "corridor_b.yaml").read_text()
    scenario_file = tmp_path / "my_corridor.yaml"
    scenario_file.write_text(text.replace("name: corridor_b", "name: my_corridor"))
    route = [(7.0, 0.0), (7.0, 8.0), (8.0, 15.1)]
    backend = replay(tmp_path / "script", ['{"object_id": "WIN2"}', plan_text(route)])
    out = tmp_path / "run"
    res = runner.invoke(
        app,
        [
            "plan",
            "--scenario",
            str(scenario_file),
            "--task",
            "Go to the window",
            "--backend",
            backend,
            "--plot",
            str(tmp_path / "p.png"),
            "--execute",
            "--out",
            str(out),
        ],
    )
    assert res.exit_code == 0, res.output
    assert "target WIN2 in my_corridor" in res.output
    record = read_run(out)
    assert record.config["scenario"] == "my_corridor"
    assert Path(record.config["scenario_file"]) == scenario_file
    # driving grounds "the window" on the plan's final point, without asking the model again
    assert record.of_type("llm_call") == []
    assert [e["target"] for e in record.of_type("planner") if e.get("kind") == "grounding"] == ["WIN2"]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["outcome"] == "completed" and summary["target_index"] == 1


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--scenario", "atlantis"], "atlantis"),
        (["--scenario", "factory"], "publishes no corridors"),
        (["--max-generations", "0"], "--max-generations 0"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(tmp_path: Path, args: list[str], message: str) -> None:
    plot = ["--plot", str(tmp_path / "p.png")]
    res = runner.invoke(app, ["plan", "--task", "Go to room 105", "--backend", "replay:/nonexistent", *plot, *args])
    assert res.exit_code == 2, res.output
    assert len(res.output.strip().splitlines()) == 1 and message in res.output, res.output
    assert "Traceback" not in res.output and not (tmp_path / "p.png").exists()


@pytest.mark.parametrize(("scenario", "task", "target"), [("corridor_a", "Go to room 105", "R105"),
                                                           ("corridor_c", "Go to room 107", "R107")])  # fmt: skip
def test_plan_with_oracle_answers(tmp_path: Path, scenario: str, task: str, target: str) -> None:
    """`policy:oracle` answers `plan` from the true map: a valid plan on the first attempt, ending on the target."""
    from llmnav.world.scenario import load_scenario

    res = runner.invoke(app, ["plan", "--task", task, "--scenario", scenario, "--backend", "policy:oracle",
                              "--plot", str(tmp_path / "p.png"), "--json"])  # fmt: skip
    assert res.exit_code == 0, res.output
    plan = json.loads(res.stdout)
    assert plan["target"] == target and plan["wgsr"] == 100.0 and len(plan["attempts"]) == 1
    goal = load_scenario(scenario).object(target).goal_point
    assert np.allclose(plan["waypoints"][-1], goal, atol=0.05)


def test_plan_figure_never_replaces_a_file(tmp_path: Path) -> None:
    figure = tmp_path / "mine.png"
    figure.write_bytes(b"the user's own picture")
    backend = replay(tmp_path / "script", [plan_text(GOOD)])
    res = runner.invoke(app, ["plan", "--task", "Go to room 105", "--backend", backend, "--plot", str(figure)])
    assert res.exit_code == 2 and "exists" in res.output and len(res.output.strip().splitlines()) == 1, res.output
    assert figure.read_bytes() == b"the user's own picture"


def test_plan_figure_goes_into_a_new_folder_each_time(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    for number in (1, 2):
        backend = replay(tmp_path / f"script{number}", [plan_text(GOOD)])
        res = runner.invoke(app, ["plan", "--task", "Go to room 105", "--backend", backend])
        assert res.exit_code == 0, res.output
    figures = sorted((tmp_path / "runs").glob("*-plan-*/plan.png"))
    assert len(figures) == 2 and figures[0].parent != figures[1].parent
    assert not (tmp_path / "plan.png").exists()
    assert all(f.read_bytes()[:4] == b"\x89PNG" for f in figures)
    assert f"plot {figures[-1].relative_to(tmp_path)}" in " ".join(res.output.split())


def test_execute_puts_the_figure_into_the_run_folder(tmp_path: Path) -> None:
    backend = replay(tmp_path / "script", [plan_text(GOOD)])
    out = tmp_path / "run"
    args = ["plan", "--task", "Go to room 105", "--backend", backend, "--execute", "--out", str(out)]
    res = runner.invoke(app, args)
    assert res.exit_code == 0, res.output
    assert (out / "plan.png").read_bytes()[:4] == b"\x89PNG" and (out / "run.jsonl").is_file()
