"""The drive views: live table rows and columns, one-line progress, the closing lines."""

from __future__ import annotations

import io
from pathlib import Path

from rich.console import Console

from llmnav.planners.base import StepInfo, drive_options
from llmnav.reporting.live import LiveView, ProgressView, print_result
from llmnav.runs.runner import EpisodeSpec


def _console() -> Console:
    return Console(file=io.StringIO(), width=140, force_terminal=False, color_system=None)


def test_live_view_shows_each_step_and_only_filled_columns() -> None:
    console = _console()
    spec = EpisodeSpec(
        scenario="factory",
        task_id="T1",
        task_text=None,
        options=drive_options(planner="stepwise"),
        backend="local",
        out_dir=Path("x"),
    )
    with LiveView(console, spec) as view:
        view.on_step(StepInfo(1, "FRONT 1 m", "the aisle ahead is open\nand wide", 3.25, 1.9, 0, 2))
        view.on_step(StepInfo(2, "ROTATE_LEFT 30°", "look left", None, 2.1, 1, 0))
    out = console.file.getvalue()  # type: ignore[attr-defined]
    assert "stepwise · factory · T1" in out
    for text in (
        "FRONT 1 m",
        "ROTATE_LEFT 30°",
        "the aisle ahead is open and wide",
        "3.25 m",
        "1.90 s",
        "JSON",
    ):
        assert text in out, text
    oracle = _console()
    with LiveView(oracle, spec) as view:
        view.on_step(StepInfo(1, "GO_TO [1, 2]"))
    assert "GO_TO [1, 2]" in oracle.file.getvalue() and "latency" not in oracle.file.getvalue()  # type: ignore[attr-defined]


def test_views_print_nothing_before_the_first_step() -> None:
    console = _console()
    with (
        ProgressView(console, 30),
        LiveView(console, EpisodeSpec(scenario="f", out_dir=Path("x"), task_id="T1", task_text=None)),
    ):
        pass
    assert console.file.getvalue() == ""  # type: ignore[attr-defined]


def test_print_result_names_outcome_score_path_and_folder() -> None:
    console = _console()
    print_result(
        console,
        {
            "outcome": "failed",
            "reason": "max iterations (30) reached",
            "score": 0.4123,
            "success": False,
            "path_length_m": 7.256,
            "iterations": 30,
            "distance_m": 3.1,
            "run_dir": "runs/x",
            "trajectory": "runs/x/trajectory.png",
        },
    )
    out = console.file.getvalue()  # type: ignore[attr-defined]
    assert "failed — max iterations (30) reached" in out
    assert "score 0.41" in out and "path 7.26 m" in out and "runs/x" in out and "trajectory.png" in out
    console = _console()
    print_result(
        console,
        {
            "outcome": "completed",
            "reason": "",
            "score": None,
            "path_length_m": 0.0,
            "iterations": 2,
            "run_dir": "r",
        },
    )
    assert "score N.A." in console.file.getvalue()  # type: ignore[attr-defined]
