"""The information model: defaults per scenario, bad modes, and planners in `sensed` mode never reading
ground truth (object positions, walls, the true pose), checked by spying on what planner code touches."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import pytest

from llmnav.errors import BadInputError
from llmnav.planners.base import EpisodeContext, drive_options
from llmnav.runs.runlog import read_run
from llmnav.runs.runner import EpisodeSpec, run_episode
from llmnav.world.knowledge import planner_modes, resolve_information, scenario_view
from llmnav.world.scenario import load_scenario

from .test_hybrid import MenuReader, first

# Attributes that hold ground truth, per object the planner is handed.
TRUTH = {"robot": {"pose"}, "world": {"scenario", "labelled", "object_bodies", "body_names"}}


LOGGED_OBSERVATION = ("robot.pose", "observe.py", "observe")  # the observation event's true pose, for scoring


class Spy:
    """Passes every attribute through; records the ones in `truth` read directly by planner code."""

    def __init__(self, target: Any, kind: str, reads: list[tuple[str, str, str]]) -> None:
        object.__setattr__(self, "_target", target)
        object.__setattr__(self, "_kind", kind)
        object.__setattr__(self, "_reads", reads)

    def __getattr__(self, name: str) -> Any:
        value = getattr(self._target, name)
        caller = sys._getframe(1)
        code = caller.f_code
        if name in TRUTH.get(self._kind, set()) and "/llmnav/planners/" in code.co_filename.replace("\\", "/"):
            where = code.co_filename.replace("\\", "/").split("/llmnav/planners/", 1)[1]  # e.g. stepwise/planner.py
            self._reads.append((f"{self._kind}.{name}", where, code.co_name))
        if self._kind == "world" and name == "robot":
            return Spy(value, "robot", self._reads)
        return value


@pytest.fixture
def spied(monkeypatch: pytest.MonkeyPatch) -> tuple[list[tuple[str, str, str]], list[EpisodeContext]]:
    """Every context the runner builds gets a spying world; returns (reads, contexts)."""
    import llmnav.runs.runner as runner

    reads: list[tuple[str, str, str]] = []
    contexts: list[EpisodeContext] = []

    def build(scenario: Any, task: Any, world: Any, *args: Any) -> EpisodeContext:
        ctx = EpisodeContext(scenario, task, Spy(world, "world", reads), *args)
        contexts.append(ctx)
        return ctx

    monkeypatch.setattr(runner, "EpisodeContext", build)
    return reads, contexts


def test_defaults_follow_whether_a_map_is_published() -> None:
    factory, corridor, maze = (load_scenario(n) for n in ("factory", "corridor_a", "maze_arena"))
    assert resolve_information("hybrid", factory, None) == "sensed"
    assert resolve_information("hybrid", maze, None) == "sensed"
    assert resolve_information("hybrid", corridor, None) == "map"
    assert resolve_information("hybrid", factory, "oracle") == "oracle"
    assert resolve_information("oracle", factory, None) == "oracle"  # a baseline's first mode, sensed or not
    assert resolve_information("frontier", maze, None) == "oracle"
    assert resolve_information("oracle", factory, "sensed") == "sensed"
    declared = {name: planner_modes(name) for name in ("stepwise", "waypoints", "fsm", "hybrid", "oracle", "frontier")}
    assert declared == {
        "stepwise": ("sensed",), "waypoints": ("map",), "fsm": ("oracle",), "hybrid": ("sensed", "map", "oracle"),
        "oracle": ("oracle", "sensed"), "frontier": ("oracle", "sensed"),
    }  # fmt: skip
    with pytest.raises(BadInputError, match="unknown planner 'teleport'"):
        planner_modes("teleport")  # once silently "oracle"


@pytest.mark.parametrize(
    ("planner", "scenario", "mode", "message"),
    [
        ("hybrid", "factory", "psychic", "--information 'psychic': expected one of map, sensed, oracle"),
        ("hybrid", "factory", "map", "--information map: scenario 'factory' publishes no map"),
        ("waypoints", "corridor_a", "sensed", "--information sensed: the waypoints planner runs with map"),
    ],
)
def test_bad_information_modes_are_one_line_errors(planner: str, scenario: str, mode: str, message: str) -> None:
    with pytest.raises(BadInputError) as err:
        resolve_information(planner, load_scenario(scenario), mode)
    assert str(err.value) == message


def test_the_sensed_view_holds_no_positions() -> None:
    factory = load_scenario("factory")
    view = scenario_view(factory, "sensed")
    assert (view.objects, view.walls, view.obstacles, view.corridors, view.tasks) == ([], [], [], [], [])
    assert view.bounds == factory.bounds and view.robot == factory.robot
    assert factory.objects and scenario_view(factory, "oracle") is factory
    # a baseline that plans on the true map keeps it when only its pose is sensed
    assert scenario_view(factory, "sensed", knows_map=True) is factory


def _t8_policy(options: dict[int, str], index: int) -> int:
    """Finish at the boxes, else go to them when listed, else look around once, else explore."""
    at_boxes = first(options, "Finish (at dark brown wooden boxes")
    going = first(options, "Go to dark brown wooden boxes")
    return at_boxes or going or first(options, "Turn a full circle") or first(options, "Explore") or 1


def test_hybrid_sensed_finds_the_boxes_without_reading_ground_truth(
    tmp_path: Path, spied: tuple[list[tuple[str, str, str]], list[EpisodeContext]]
) -> None:
    reads, contexts = spied
    reader = MenuReader(_t8_policy)
    spec = EpisodeSpec(
        scenario="factory",
        task_id="T8",
        start_pose=4,
        options=drive_options(planner="hybrid", sensing=("lidar", "detections"), max_iterations=12),
        backend=reader.spec,
        out_dir=tmp_path / "run",
        plots=False,
    )
    summary = run_episode(spec, backend_obj=reader)
    (ctx,) = contexts
    assert ctx.information == "sensed" and ctx.scenario.objects == [] and ctx.scenario.walls == []
    # no true pose, no world internals: only odometry, LiDAR, detector and motion; the observation logger
    # (llmnav/planners/observe.py) reads the true pose into the run log alone, never into what it returns
    assert set(reads) <= {LOGGED_OBSERVATION}
    assert summary["information"] == "sensed" and summary["outcome"] == "completed", summary["reason"]
    assert summary["success"] and summary["collisions"] == 0
    config = read_run(tmp_path / "run").config
    assert config["information"] == "sensed" and config["task"]["wording"] == "bundled"
    assert config["options"]["menu_order"] == "distance"


def test_stepwise_sensed_reads_the_true_pose_only_to_log_it(
    tmp_path: Path, spied: tuple[list[tuple[str, str, str]], list[EpisodeContext]]
) -> None:
    from llmnav.backends.replay import ReplayBackend, write_script

    reads, contexts = spied
    from .test_stepwise import answer

    # A motion's action is logged from the poses its result carries; COMPLETE moves nothing, so its
    # action reads the pose once.
    answers = [answer("ROTATE_LEFT", 90), answer("ROTATE_LEFT", 90), answer("COMPLETE", 0)]
    replay = ReplayBackend(write_script(tmp_path / "script", answers, purpose="action", latency_s=0.1))
    spec = EpisodeSpec(
        scenario="factory",
        task_id="T7",
        options=drive_options(planner="stepwise", sensing=("lidar",), max_iterations=3),
        backend=replay.spec,
        out_dir=tmp_path / "run",
        plots=False,
    )
    summary = run_episode(spec, backend_obj=replay)
    assert contexts[0].information == "sensed" and contexts[0].scenario.objects == []
    assert summary["information"] == "sensed"
    expected = {("robot.pose", "stepwise/planner.py", "_log_action"), LOGGED_OBSERVATION}
    assert reads and {(what, where, fn) for what, where, fn in reads} == expected


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--information", "psychic"], "--information: Input should be 'map', 'sensed' or 'oracle'"),
        (["--menu-order", "magic"], "--menu-order: Input should be 'distance' or 'relevance'"),
        (["--information", "map"], "--information map: scenario 'factory' publishes no map"),
    ],
)
def test_bad_modes_on_the_command_line_are_one_line_and_exit_2(tmp_path: Path, args: list[str], message: str) -> None:
    import subprocess

    out = tmp_path / "run"
    command = [sys.executable, "-c", "from llmnav.cli import main; main()", "drive", "--task-id", "T1"]
    result = subprocess.run(
        [*command, "--planner", "hybrid", "--backend", "replay:none", *args, "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1 and message in result.stderr, result.stderr
    assert not out.exists()
