"""Planners plug in like backends: the `llmnav.planners` entry-point group, a third-party planner run by the
runner, per-planner options that `drive` and `ablate` report when they do not apply, and hooks the runner
calls after the log closes."""

from __future__ import annotations

import json
from collections.abc import Callable
from importlib.metadata import entry_points
from pathlib import Path

import pytest
from pydantic import ValidationError
from typer.testing import CliRunner

from llmnav.cli import app
from llmnav.errors import BadInputError
from llmnav.planners.base import (
    DriveOptions,
    drive_options,
    inapplicable_options,
    planner_class,
    planner_names,
    planner_options,
)
from llmnav.runs.runlog import read_run
from llmnav.runs.runner import EpisodeSpec, run_episode

SMALL = str(Path(__file__).parent / "small_room.yaml")
BUILT_IN = {"stepwise", "waypoints", "fsm", "hybrid", "oracle", "frontier"}


def test_the_entry_point_group_lists_all_six() -> None:
    assert BUILT_IN <= {ep.name for ep in entry_points(group="llmnav.planners")}
    with pytest.raises(ValidationError, match="unknown planner 'teleport'"):
        DriveOptions(planner="teleport")
    with pytest.raises(BadInputError, match="unknown planner 'teleport'"):
        drive_options(planner="teleport")


THIRD_PARTY = '''
import math
from typing import ClassVar
from llmnav.planners.base import EpisodeContext, EpisodeOutcome, Planner


class SpinPlanner(Planner):
    name: ClassVar[str] = "spin"
    needs_backend: ClassVar[bool] = False
    options = frozenset({"max_iterations"})

    def run(self, ctx: EpisodeContext) -> EpisodeOutcome:
        for _ in range(ctx.options.max_iterations):
            ctx.world.motion.rotate(math.pi / 2)
        blocked = ctx.world.motion.drive(20.0)  # through the east wall: the layer refuses it
        return EpisodeOutcome("completed", blocked.stopped_reason or "moved", ctx.options.max_iterations)

    def summarize(self, record, scenario, task):
        return {"turns_logged": len(record.of_type("pose"))}
'''


def test_a_third_party_planner_installs_by_entry_point_and_gets_the_guarded_layer(
    tmp_path: Path, install_planner: Callable[[str, str, str], None]
) -> None:
    install_planner("spin", "spin_planner:SpinPlanner", THIRD_PARTY)
    assert "spin" in planner_names()
    spec = EpisodeSpec(
        scenario=SMALL, task_id="T1", start_pose=2, options={"planner": "spin", "max_iterations": 4},
        out_dir=tmp_path / "run", plots=False,
    )  # fmt: skip
    summary = run_episode(spec)
    assert (summary["outcome"], summary["reason"]) == ("completed", "vetoed")
    assert summary["planner_metrics"]["turns_logged"] > 4  # the summarize hook ran on the closed log
    assert [g["outcome"] for g in read_run(tmp_path / "run").of_type("guard")] == ["veto"]
    assert summary["collisions"] == 0


def test_options_a_planner_ignores_are_named() -> None:
    options, ignored = planner_options("oracle", {"history": "1", "lidar_sectors": 5, "seed": 3})
    assert ignored == ["history", "lidar_sectors"]
    assert options.seed == 3 and "history" not in type(options).model_fields  # not applied: not its option
    assert inapplicable_options("stepwise", {"history", "lidar_sectors", "assist"}) == ["assist"]
    assert inapplicable_options("fsm", {"assist", "alpha", "prompt"}) == ["prompt"]


def test_an_option_no_planner_takes_is_refused_naming_what_it_takes() -> None:
    with pytest.raises(BadInputError, match="'asist': no planner takes it") as err:
        planner_options("fsm", {"asist": "llm"})
    assert "assist" in str(err.value).split("takes:")[1]


def test_each_planner_owns_its_options_model() -> None:
    for name in planner_names():
        model = planner_class(name).Options
        assert issubclass(model, DriveOptions) and model.model_config.get("extra") == "forbid"
        with pytest.raises(ValidationError):
            model.model_validate({"planner": name, "no_such_option": 1})
    shared = set(DriveOptions.model_fields)
    own = {name: set(planner_class(name).Options.model_fields) - shared for name in planner_names()}
    assert "assist" in own["fsm"] and "assist" not in own["hybrid"]
    assert "prompt" in own["stepwise"] and "prompt" not in own["waypoints"]


def test_drive_and_ablate_say_which_flags_do_not_apply(tmp_path: Path) -> None:
    runner = CliRunner()
    drove = runner.invoke(
        app,
        ["drive", "--scenario", SMALL, "--task-id", "T1", "--planner", "oracle", "--history", "1",
         "--out", str(tmp_path / "drive"), "--quiet"],
    )  # fmt: skip
    assert drove.exit_code == 0, drove.output
    assert "--history do(es) not apply to planner 'oracle'" in drove.output
    ablated = runner.invoke(
        app,
        ["ablate", "--scenario", SMALL, "--planner", "oracle", "--tasks", "T1", "--poses", "1", "--prompt",
         "short", "--out", str(tmp_path / "ablate"), "--dry-run"],
    )  # fmt: skip
    assert ablated.exit_code == 0, ablated.output
    assert "prompt do(es) not apply to planner 'oracle'" in ablated.output


def test_planner_figures_follow_the_plots_setting(tmp_path: Path) -> None:
    for plots in (False, True):
        out = tmp_path / f"fsm-{plots}"
        spec = EpisodeSpec(
            scenario="maze_arena", task_id="M1", options={"planner": "fsm", "max_ticks": 150}, out_dir=out,
            plots=plots,
        )  # fmt: skip
        summary = run_episode(spec)
        assert (out / "velocity_profile.png").exists() == plots
        assert json.loads((out / "summary.json").read_text())["outcome"] == summary["outcome"]


def test_no_module_above_the_planners_names_one() -> None:
    # The runner used to special-case the FSM by name; hooks replaced that.
    runner_source = (Path(__file__).parents[2] / "llmnav" / "runs" / "runner.py").read_text()
    assert '"fsm"' not in runner_source and "'fsm'" not in runner_source


def test_malformed_option_pairs_are_one_line_errors(tmp_path: Path) -> None:
    runner = CliRunner()
    for pair, needle in (("alpha", "expected KEY=VALUE"), ("planner=fsm", "--planner"), ("asist=llm", "'asist'")):
        result = runner.invoke(app, ["drive", "--scenario", SMALL, "--task-id", "T1", "--planner", "fsm", "-o", pair,
                                     "--out", str(tmp_path / pair)])  # fmt: skip
        assert result.exit_code == 2 and needle in result.output, (pair, result.output)
        assert len(result.output.strip().splitlines()) == 1 and not (tmp_path / pair).exists()
