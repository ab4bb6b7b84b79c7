"""`llmnav plan`: generate and validate waypoints only (source B); `--execute` drives them."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from llmnav.commands.common import cli_errors, console, esc, path_option, plot_option, print_data
from llmnav.errors import BadInputError, printable

if TYPE_CHECKING:
    from llmnav.backends.base import Backend
    from llmnav.core.geometry import Pose2D
    from llmnav.planners.waypoints.planner import PlanResult
    from llmnav.world.scenario import Scenario
    from llmnav.world.tasks import ResolvedTask


@cli_errors
def plan(
    task: Annotated[str | None, typer.Option("--task", help="Command naming a target, e.g. 'Go to room 101'.")] = None,
    task_audio: Annotated[
        Path | None, typer.Option("--task-audio", help="A spoken command (WAV) instead of --task.")
    ] = None,
    asr_free: Annotated[bool, typer.Option("--asr-free", help="Voice: open language model, no grammar.")] = False,
    scenario: Annotated[str | None, typer.Option(help="Scenario (default: the corridor the task names).")] = None,
    start_pose: Annotated[int, typer.Option("--start-pose", help="Start pose K (1-based).")] = 1,
    backend: Annotated[str, typer.Option(help="Model backend spec NAME[:ARG].")] = "local",
    max_generations: Annotated[int, typer.Option("--max-generations", help="Attempts before giving up.")] = 5,
    seed: Annotated[int, typer.Option(help="Model seed.")] = 0,
    plot: Annotated[
        str | None,
        typer.Option(
            help="Write the plan figure to this new file (never over an existing one). Default: plan.png in the "
            "run folder (with --execute) or in a new folder runs/<time>-plan-<task>."
        ),
    ] = None,
    json_output: Annotated[bool, typer.Option("--json", help="Print the plan as JSON only.")] = False,
    execute: Annotated[bool, typer.Option(help="Drive the valid plan (drive --planner waypoints).")] = False,
    out: Annotated[str | None, typer.Option(help="Run folder for --execute.")] = None,
) -> None:
    """Ask the model for waypoints to a target, validate every attempt, and show the verdicts."""
    # deferred: the backends, the grid and the planner bring pydantic, yaml and numpy (about 0.3 s), not for
    # `llmnav --help`
    from llmnav.backends.base import ChatRequest, ChatResult, get_backend
    from llmnav.mapping.grid import build_grid
    from llmnav.planners.waypoints.planner import PlanningClock, generate_plan, ground_target, plan_summary
    from llmnav.world.tasks import resolve_task

    out_dir = path_option(out, "--out")
    plot_path = plot_option(plot)  # checked before any model work
    if plot_path is not None and os.path.lexists(plot_path):
        raise BadInputError(f"--plot {plot_path}: exists; llmnav plan never replaces a file, choose another name")
    if (task is None) == (task_audio is None):
        raise BadInputError("give exactly one of --task TEXT or --task-audio FILE.wav")
    if task_audio is not None:
        # deferred: speech recognition only for a spoken command
        from llmnav.commands.transcribe import audio_task

        task = audio_task(task_audio, scenario, asr_free)
    assert task is not None
    if max_generations < 1:
        raise BadInputError(f"--max-generations {max_generations}: must be at least 1")
    resolved = resolve_task(scenario, [task], None, start_pose)
    sc = resolved.scenario
    if not sc.corridors:
        raise BadInputError(f"scenario '{sc.name}' publishes no corridors; waypoint planning needs them")
    model = get_backend(backend)
    _attach_oracle_answers(model, resolved)

    def call(request: ChatRequest, purpose: str) -> ChatResult:
        return model.chat(request)

    try:
        clock = PlanningClock(call)  # command -> waypoints: grounding counts too
        target = ground_target(sc, resolved.task, clock)
        grounding_s = clock.elapsed_s()
        start = resolved.start.pose()
        result = generate_plan(sc, target, start, call, max_generations=max_generations, grid=build_grid(sc), seed=seed)
        result.planning_time_s += grounding_s
        run_dir = None
        if execute and result.waypoints is not None:
            # deferred: the drive command's module scans the planners' flags, only to name a run folder
            from llmnav.commands.drive import default_out_dir

            run_dir = out_dir or default_out_dir("waypoints", resolved.task.text)
        if plot_path is None and run_dir is None:
            # deferred: as above, only to name a folder for the figure
            from llmnav.commands.drive import default_out_dir

            plot_path = default_out_dir("plan", resolved.task.text) / PLAN_FILE
        if plot_path is not None:
            _write_figure(sc, result, start, plot_path)
        if json_output:
            print_data(json.dumps(plan_summary(result)))
        else:
            _print_plan(result, sc.name, plot_path or (run_dir / PLAN_FILE if run_dir else None))
        if result.waypoints is None:
            raise typer.Exit(1)
        if execute:
            # the scenario as the user gave it (a file path stays a path); the same backend object, so a
            # replay continues where planning stopped and a local model is not loaded twice
            assert run_dir is not None
            figure = (sc, result, start) if plot_path is None else None  # into the run folder, once it holds the run
            _execute(resolved, scenario or sc.name, model, result.waypoints, max_generations, seed, run_dir, figure)
    finally:
        model.close()


def _attach_oracle_answers(model: Backend, resolved: ResolvedTask) -> None:
    """`policy:oracle`: the waypoint planner's answer key, from the true map and the start pose (nothing moves)."""
    # deferred: the planner and the runner (pybullet among them, about 0.5 s) only for oracle answers
    from llmnav.planners.base import GroundTruth
    from llmnav.planners.waypoints.planner import WaypointPlanner
    from llmnav.planners.waypoints.planner.options import WaypointOptions
    from llmnav.runs.runner import oracle_backend

    oracle = oracle_backend(model)
    if oracle is None:
        return
    start = resolved.start.pose()
    truth = GroundTruth(resolved.scenario, resolved.task, lambda: start, lambda: 0.0)
    oracle.attach_answer_key(WaypointPlanner().oracle_answers(truth, WaypointOptions(planner="waypoints")))


PLAN_FILE = "plan.png"


def _write_figure(sc: Scenario, result: PlanResult, start: Pose2D, path: Path) -> None:
    """Draw the plan into a new file at `path`: made aside and linked into place, so nothing is ever replaced."""
    # deferred: the figure brings matplotlib (about 0.3 s), only when a plan is drawn
    from llmnav.core.safefiles import private_dir
    from llmnav.planners.waypoints.figure import plot_plan

    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with private_dir(path.parent) as work:
            tmp = plot_plan(sc, result, start, work / ("figure" + path.suffix))
            os.link(tmp, path)  # fails if anything is at `path` by now (another plan's figure, a link)
    except FileExistsError:
        raise BadInputError(f"--plot {path}: exists; llmnav plan never replaces a file, choose another name") from None
    except OSError as err:
        raise BadInputError(f"--plot {path}: cannot write: {err.strerror or err}") from None


def _print_plan(result: PlanResult, scenario: str, plot: Path | None) -> None:
    # deferred: rich's table (about 5 ms) only when a plan is printed, not for `llmnav --help`
    from rich.table import Table
    from rich.text import Text

    table = Table(title=f"Waypoint attempts — target {esc(result.target_id)} in {esc(scenario)}")
    table.add_column("#", justify="right")
    table.add_column("waypoints")
    table.add_column("verdict")
    for attempt in result.attempts:
        points = " → ".join(f"({x:.2f}, {y:.2f})" for x, y in attempt.points) or "—"
        # model text and validator messages may hold brackets: plain Text, never markup
        problems = "\n".join(printable(p) for p in attempt.problems)
        verdict = Text("valid", style="green") if attempt.valid else Text(problems, "red")
        table.add_row(str(attempt.number), points, verdict)
    console.print(table)
    console.print(
        f"planning time {result.planning_time_s:.2f} s · WGSR {result.wgsr:.1f} %"
        + (f" · plot {plot}" if plot else ""),
        markup=False,
        highlight=False,
    )


def _execute(
    resolved: ResolvedTask,
    scenario: str,
    model: Backend,
    waypoints: list[tuple[float, float]],
    max_generations: int,
    seed: int,
    out: Path,
    figure: tuple[Scenario, PlanResult, Pose2D] | None = None,
) -> None:
    # deferred: the runner and the simulator (pybullet, about 0.5 s) only with --execute
    from llmnav.planners.base import drive_options
    from llmnav.reporting.live import print_result
    from llmnav.runs.runner import EpisodeSpec, exit_code, run_episode

    options = drive_options(
        "waypoints",
        seed=seed,
        max_generations=max_generations,
        preset_waypoints=tuple(waypoints),
    )
    spec = EpisodeSpec(
        scenario=scenario,
        task_text=resolved.task.text,
        start_pose=resolved.start_pose_index,
        options=options,
        backend=model.spec,
        out_dir=out,
    )
    summary = run_episode(spec, backend_obj=model)
    if figure is not None:
        _write_figure(*figure, out / PLAN_FILE)
    print_result(console, summary)
    raise typer.Exit(exit_code(summary))
