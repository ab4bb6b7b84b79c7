"""`llmnav drive`: run one episode (argument parsing only; the work is `llmnav.runner.run_episode`)."""

from __future__ import annotations

import json
import math
import re
import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from pydantic import ValidationError

from llmnav.commands.common import cli_errors, console, err_console, esc, fail, parse_sensing, path_option, print_data
from llmnav.errors import BadInputError

if TYPE_CHECKING:
    from llmnav.runner import EpisodeSpec


# DriveOptions fields whose flag is not the field's name with dashes
_FLAGS = {"lidar_fov_deg": "--lidar-fov", "obstacles": "--obstacle"}


def _option_error(err: ValidationError) -> BadInputError:
    """A pydantic error on DriveOptions as one line naming the flag."""
    first = err.errors()[0]
    field = str(first["loc"][0]) if first["loc"] else "options"
    flag = _FLAGS.get(field, "--" + field.replace("_", "-"))
    return BadInputError(f"{flag}: {first['msg'].removeprefix('Value error, ')} (got {first.get('input')!r})")


def _parse_obstacle(text: str) -> tuple[float, float]:
    try:
        x, y = (float(v) for v in text.split(","))
    except ValueError:
        raise BadInputError(f"--obstacle {text!r}: expected X,Y in metres, e.g. 3.5,-1") from None
    if not (math.isfinite(x) and math.isfinite(y)):
        raise BadInputError(f"--obstacle {text!r}: coordinates must be finite numbers")
    return (x, y)


def _slug(text: str, limit: int = 32) -> str:
    return re.sub(r"[^a-z0-9]+", "-", text.lower()).strip("-")[:limit].rstrip("-") or "task"


def default_out_dir(planner: str, task_label: str, root: Path = Path("runs")) -> Path:
    """`runs/<timestamp>-<planner>-<task>`, made unique with a counter when it exists."""
    base = root / f"{time.strftime('%Y%m%d-%H%M%S')}-{planner}-{_slug(task_label)}"
    path, n = base, 1
    while path.exists():
        n += 1
        path = base.with_name(f"{base.name}-{n}")
    return path


@cli_errors
def drive(
    task: Annotated[
        list[str] | None, typer.Option("--task", help="Task text (repeat for a sequence of targets).")
    ] = None,
    task_id: Annotated[str | None, typer.Option("--task-id", help="A scenario task id, e.g. T1.")] = None,
    task_audio: Annotated[
        Path | None, typer.Option("--task-audio", help="A spoken command (WAV), transcribed offline.")
    ] = None,
    asr_free: Annotated[
        bool, typer.Option("--asr-free", help="Voice: open language model instead of the scenario grammar.")
    ] = False,
    scenario: Annotated[
        str | None,
        typer.Option(help="Scenario name or YAML path (default: the one the task names, else factory)."),
    ] = None,
    start_pose: Annotated[int, typer.Option("--start-pose", help="Start pose K (1-based) of the task.")] = 1,
    backend: Annotated[
        str, typer.Option(help="Model backend spec NAME[:ARG], e.g. ollama:llama3.1.")
    ] = "local",
    planner: Annotated[
        str, typer.Option(help="stepwise | waypoints | fsm | hybrid | oracle | frontier")
    ] = "hybrid",
    information: Annotated[
        str | None,
        typer.Option(help="What the planner may know: map | sensed | oracle (default: map where published)."),
    ] = None,
    menu_order: Annotated[
        str, typer.Option("--menu-order", help="Hybrid menu order: distance (neutral) | relevance.")
    ] = "distance",
    decide: Annotated[
        str,
        typer.Option(help="Hybrid: score option texts | generate an option number | auto (score if the backend can)."),
    ] = "auto",
    sensing: Annotated[str, typer.Option(help="Comma list of lidar, image, detections.")] = "lidar,image",
    lidar_sectors: Annotated[int, typer.Option("--lidar-sectors", help="LiDAR sectors in the summary.")] = 8,
    lidar_fov: Annotated[
        float, typer.Option("--lidar-fov", help="LiDAR summary field of view in degrees.")
    ] = 90.0,
    prompt: Annotated[str, typer.Option(help="Prompt variant (see prompts/).")] = "full",
    history: Annotated[str, typer.Option(help="Previous exchanges re-sent: all | 0 | 1 | 2.")] = "all",
    self_check: Annotated[
        bool, typer.Option("--self-check", help="Ask the model to confirm each answer.")
    ] = False,
    max_iterations: Annotated[
        int, typer.Option("--max-iterations", help="Decision steps before failing.")
    ] = 30,
    seed: Annotated[int, typer.Option(help="Simulation and model seed.")] = 0,
    out: Annotated[
        str | None, typer.Option(help="Run folder (default runs/<time>-<planner>-<task>).")
    ] = None,
    realtime: Annotated[
        bool, typer.Option("--realtime", help="Pace the simulation to the wall clock.")
    ] = False,
    quiet: Annotated[
        bool, typer.Option("--quiet", help="One progress line instead of the live view.")
    ] = False,
    json_output: Annotated[
        bool, typer.Option("--json", help="Print only one JSON summary at the end.")
    ] = False,
    assist: Annotated[str, typer.Option(help="FSM assist: none | ema | llm.")] = "none",
    model_latency: Annotated[
        str | None,
        typer.Option("--model-latency", help="FSM: latency charged to sim time: MS | measured | recorded."),
    ] = None,
    ttl: Annotated[str | None, typer.Option("--ttl", help="FSM: suggestion TTL in ms, or auto.")] = None,
    obstacle: Annotated[
        list[str] | None, typer.Option(help="Drop an unexpected box obstacle at X,Y metres (repeatable).")
    ] = None,
    replay_loose: Annotated[
        bool, typer.Option("--replay-loose", help="Replay: answer in order even when prompts differ.")
    ] = False,
    view_page: Annotated[
        bool, typer.Option("--view", help="Write the run's HTML page (view.html) at the end and print its path.")
    ] = False,
    drop_images: Annotated[
        bool, typer.Option("--drop-images", help="A server that takes no images: go on without them.")
    ] = False,
) -> None:
    """Drive the robot through one task and write a run folder (log, summary, trajectory plot)."""
    from llmnav.planners.base import DriveOptions
    from llmnav.planners.fsm import timing_options
    from llmnav.runner import EpisodeSpec, exit_code
    from llmnav.tasks import SEQUENCE_JOIN, default_scenario

    out_dir = path_option(out, "--out")
    if task and not all(t.strip() for t in task):
        raise BadInputError("--task: empty task text; say where to go, e.g. --task 'go to the red box'")
    texts = [t for t in (task or []) if t.strip()]
    if task_audio is not None:
        if texts or task_id is not None:
            raise BadInputError("give --task-audio alone, without --task or --task-id")
        from llmnav.commands.transcribe import audio_task

        # Transcribed before anything is built or moves: an unknown command ends here with exit 2.
        texts = [audio_task(task_audio, scenario, asr_free, quiet=json_output)]
    if bool(texts) == (task_id is not None):
        raise BadInputError("give exactly one of --task TEXT (repeatable) or --task-id ID")
    if any(SEQUENCE_JOIN in t for t in texts):
        raise BadInputError(f"--task: a task text may not contain {SEQUENCE_JOIN!r}; repeat --task instead")
    try:
        options = DriveOptions.model_validate(
            {
                "planner": planner,
                "information": information,
                "menu_order": menu_order,
                "decide": decide,
                "sensing": parse_sensing(sensing),
                "lidar_sectors": lidar_sectors,
                "lidar_fov_deg": lidar_fov,
                "prompt": prompt,
                "history": history,
                "self_check": self_check,
                "max_iterations": max_iterations,
                "seed": seed,
                "realtime": realtime,
                "assist": assist,
                "obstacles": tuple(_parse_obstacle(o) for o in obstacle or []),
                "drop_images": drop_images,
                **timing_options(model_latency, ttl, backend),
            }
        )
    except ValidationError as err:
        raise _option_error(err) from None
    backend_spec = _with_replay_mode(backend, replay_loose)
    scenario_name = scenario or default_scenario(texts, task_id)
    spec = EpisodeSpec(
        scenario=scenario_name,
        task_id=task_id,
        task_text=SEQUENCE_JOIN.join(texts) if texts else None,
        start_pose=start_pose,
        options=options,
        backend=backend_spec,
        out_dir=out_dir or default_out_dir(options.planner, task_id or (texts[0] if texts else "task")),
        quiet=quiet or json_output,
    )
    summary = _run_with_view(spec, quiet=quiet, json_output=json_output)
    _note_inapplicable(options)  # after the run: a failure to start stays one error line
    if json_output:
        print_data(json.dumps(summary, default=str))
    else:
        from llmnav.reporting.live import print_result

        print_result(console, summary)
    if view_page:
        from llmnav.view.api import write_view

        err_console.print(f"page: {esc(str(write_view(spec.out_dir).page))}", highlight=False, soft_wrap=True)
    if summary.get("trajectory_error"):  # the run is kept, but a missing figure is not a silent success
        raise fail(f"trajectory.png not written: {summary['trajectory_error']}", 1)
    raise typer.Exit(exit_code(summary))


def _note_inapplicable(options: Any) -> None:
    """One line on stderr naming the given flags the chosen planner ignores."""
    from llmnav.planners.base import changed_options, inapplicable_options

    unused = inapplicable_options(options.planner, changed_options(options))
    if unused:
        flags = ", ".join("--" + name.replace("_", "-") for name in unused)
        err_console.print(f"note: {flags} do(es) not apply to planner '{options.planner}'", highlight=False)


def _with_replay_mode(backend: str, loose: bool) -> str:
    """Replay backends take their matching mode in the spec; `--replay-loose` adds it."""
    if not loose:
        return backend
    if not backend.lower().startswith("replay:"):
        raise BadInputError("--replay-loose only applies to --backend replay:RUN_DIR")
    return backend + ("&" if "?" in backend else "?") + "loose"


def _run_with_view(spec: EpisodeSpec, *, quiet: bool, json_output: bool) -> dict[str, Any]:
    from llmnav.planners.base import NullView
    from llmnav.reporting.live import LiveView, ProgressView
    from llmnav.runner import run_episode

    if json_output:
        return run_episode(spec, view=NullView())
    view = ProgressView(console, spec.options.max_iterations) if quiet else LiveView(console, spec)
    with view:
        return run_episode(spec, view=view)
