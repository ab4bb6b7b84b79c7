"""`llmnav drive`: run one episode (argument parsing only; the work is `llmnav.runs.runner.run_episode`)."""

from __future__ import annotations

import json
import math
import re
import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from llmnav.commands.common import (
    CacheOption,
    DropImagesOption,
    PricesOption,
    cli_errors,
    console,
    err_console,
    esc,
    fail,
    parse_option_pairs,
    parse_sensing,
    path_option,
    print_data,
)
from llmnav.commands.planner_flags import GIVEN, DriveFlags, flag_of
from llmnav.commands.transcribe import audio_task
from llmnav.errors import BadInputError
from llmnav.planners import DEFAULT_PLANNER

if TYPE_CHECKING:
    from collections.abc import Callable

    from pydantic import ValidationError

    from llmnav.runs.runner import EpisodeSpec


# Option keys whose flag is not the key with dashes (a planner's own flags say so on their declarations)
_FLAGS = {
    "lidar_fov_deg": "--lidar-fov",
    "obstacles": "--obstacle",
    "appearing": "--obstacle",
}


def _flag(key: str) -> str:
    """The flag that sets option `key`."""
    return _FLAGS.get(key) or flag_of(key) or "--" + key.replace("_", "-")


def _option_error(err: ValidationError, from_o: set[str]) -> BadInputError:
    """A pydantic error on the planner's options as one line naming the flag (or `-o KEY`)."""
    first = err.errors()[0]
    field = str(first["loc"][0]) if first["loc"] else "options"
    flag = f"-o {field}" if field in from_o else _flag(field)
    return BadInputError(f"{flag}: {first['msg'].removeprefix('Value error, ')} (got {first.get('input')!r})")


def _parse_obstacle(text: str) -> tuple[float, ...]:
    """`X,Y` [m], or `X,Y@T` [m, m, s]: a box that appears when the simulation clock reaches T."""
    where, _, when = text.partition("@")
    try:
        x, y = (float(v) for v in where.split(","))
        t = float(when) if when else None
    except ValueError:
        raise BadInputError(
            f"--obstacle {text!r}: expected X,Y in metres, or X,Y@T with T in seconds, e.g. 3.5,-1@8"
        ) from None
    if not all(math.isfinite(v) for v in (x, y, t if t is not None else 0.0)):
        raise BadInputError(f"--obstacle {text!r}: coordinates and time must be finite numbers")
    if t is not None and t < 0:
        raise BadInputError(f"--obstacle {text!r}: the time it appears must be >= 0 s")
    return (x, y) if t is None else (x, y, t)


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
    ctx: typer.Context,
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
    backend: Annotated[str, typer.Option(help="Model backend spec NAME[:ARG], e.g. ollama:llama3.1.")] = "local",
    planner: Annotated[
        str, typer.Option(help="A planner registered under llmnav.planners (built in: see `llmnav planners`).")
    ] = DEFAULT_PLANNER,
    option: Annotated[
        list[str] | None,
        typer.Option("-o", "--option", help="KEY=VALUE: any option of the planner (repeatable), e.g. -o alpha=0.3."),
    ] = None,
    information: Annotated[
        str | None,
        typer.Option(help="What the planner may know: map | sensed | oracle (default: map where published)."),
    ] = None,
    decide: Annotated[
        str | None,
        typer.Option(help="Choices: score option texts | generate an answer | auto (score if the backend can)."),
    ] = None,
    sensing: Annotated[str | None, typer.Option(help="Comma list of lidar, image, detections.")] = None,
    lidar_sectors: Annotated[
        int | None, typer.Option("--lidar-sectors", help="LiDAR sectors in the summary [default: 8].")
    ] = None,
    lidar_fov: Annotated[
        float | None, typer.Option("--lidar-fov", help="LiDAR summary field of view in degrees [default: 90].")
    ] = None,
    max_iterations: Annotated[
        int | None, typer.Option("--max-iterations", help="Decision steps before failing [default: 30].")
    ] = None,
    seed: Annotated[int, typer.Option(help="Simulation and model seed.")] = 0,
    out: Annotated[str | None, typer.Option(help="Run folder (default runs/<time>-<planner>-<task>).")] = None,
    realtime: Annotated[bool, typer.Option("--realtime", help="Pace the simulation to the wall clock.")] = False,
    quiet: Annotated[bool, typer.Option("--quiet", help="One progress line instead of the live view.")] = False,
    json_output: Annotated[bool, typer.Option("--json", help="Print only one JSON summary at the end.")] = False,
    obstacle: Annotated[
        list[str] | None,
        typer.Option(
            help="Drop an unexpected box obstacle at X,Y metres, or at X,Y@T once the clock reaches T seconds "
            "(repeatable)."
        ),
    ] = None,
    replay_loose: Annotated[
        bool, typer.Option("--replay-loose", help="Replay: answer in order even when prompts differ.")
    ] = False,
    view_page: Annotated[
        bool, typer.Option("--view", help="Write the run's HTML page (view.html) at the end and print its path.")
    ] = False,
    drop_images: DropImagesOption = False,
    cache: CacheOption = None,
    prices: PricesOption = None,
    record_hz: Annotated[
        float | None,
        typer.Option(
            "--record-hz",
            help="Also log full LiDAR scans, odometry and velocity at this rate [Hz] (for `llmnav export --mcap`).",
        ),
    ] = None,
    foxglove: Annotated[
        int | None,
        typer.Option(
            "--foxglove",
            min=1,
            max=65535,
            help="Live view for Foxglove on ws://127.0.0.1:PORT (records scans at --record-hz, default 4).",
        ),
    ] = None,
) -> None:
    """Drive the robot through one task and write a run folder (log, summary, trajectory plot)."""
    # deferred: pydantic and yaml (about 0.15 s, via the runner), not for `llmnav --help`
    from pydantic import ValidationError

    from llmnav.planners.base import planner_options
    from llmnav.runs.runner import EpisodeSpec, exit_code
    from llmnav.world.tasks import SEQUENCE_JOIN, default_scenario

    out_dir = path_option(out, "--out")
    if record_hz is not None:
        # deferred: the recorder brings numpy (about 0.1 s), only with --record-hz
        from llmnav.ros.record import check_rate

        try:
            check_rate(record_hz)
        except ValueError as err:
            raise BadInputError(f"--record-hz: {err}") from None
    if task and not all(t.strip() for t in task):
        raise BadInputError("--task: empty task text; say where to go, e.g. --task 'go to the red box'")
    texts = [t for t in (task or []) if t.strip()]
    if task_audio is not None:
        if texts or task_id is not None:
            raise BadInputError("give --task-audio alone, without --task or --task-id")

        # Transcribed before anything is built or moves: an unknown command ends here with exit 2.
        texts = [audio_task(task_audio, scenario, asr_free, quiet=json_output)]
    if bool(texts) == (task_id is not None):
        raise BadInputError("give exactly one of --task TEXT (repeatable) or --task-id ID")
    if any(SEQUENCE_JOIN in t for t in texts):
        raise BadInputError(f"--task: a task text may not contain {SEQUENCE_JOIN!r}; repeat --task instead")
    parsed = [_parse_obstacle(o) for o in obstacle or []]
    named = {
        "information": information,
        "decide": decide,
        "sensing": parse_sensing(sensing) if sensing is not None else None,
        "lidar_sectors": lidar_sectors,
        "lidar_fov_deg": lidar_fov,
        "max_iterations": max_iterations,
        "seed": seed,
        "realtime": realtime or None,
        "obstacles": tuple(o for o in parsed if len(o) == 2) or None,
        "appearing": tuple(o for o in parsed if len(o) == 3) or None,
        "drop_images": drop_images or None,
        **ctx.meta.get(GIVEN, {}),  # the planners' own flags (llmnav.commands.planner_flags)
    }
    from_o = parse_option_pairs(option)
    given = {**{k: v for k, v in named.items() if v is not None}, **from_o}
    try:
        options, ignored = planner_options(planner, given)
    except ValidationError as err:
        raise _option_error(err, set(from_o)) from None
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
        record_hz=record_hz if record_hz is not None or foxglove is None else 4.0,
        foxglove_port=foxglove,
        cache_dir=path_option(cache, "--cache"),
        prices=path_option(prices, "--prices"),
    )
    if foxglove is not None:
        err_console.print(f"Foxglove live view: ws://127.0.0.1:{foxglove}", highlight=False)
    later: list[Callable[[], None]] = []  # the figures: drawn after the result is shown
    summary = _run_with_view(spec, quiet=quiet, json_output=json_output, later=later)
    _note_inapplicable(options.planner, ignored, set(from_o))  # after the run: a failure to start stays one line
    if json_output:
        for draw in later:  # the JSON names what was written
            draw()
        print_data(json.dumps(summary, default=str))
    else:
        # deferred: the live view brings pydantic (about 0.1 s), not for `llmnav --help`
        from llmnav.reporting.live import print_result

        print_result(console, summary)  # summary.json is written: an interrupted plot loses no result
        for draw in later:
            draw()
    if view_page:
        # deferred: the page writer brings pydantic and yaml (about 0.15 s), only with --view
        from llmnav.view.api import write_view

        err_console.print(f"page: {esc(str(write_view(spec.out_dir).page))}", highlight=False, soft_wrap=True)
    if summary.get("trajectory_error"):  # the run is kept, but a missing figure is not a silent success
        raise fail(f"trajectory.png not written: {summary['trajectory_error']}", 1)
    raise typer.Exit(exit_code(summary))


drive.command_class = DriveFlags  # type: ignore[attr-defined]  # the planners' flags join drive's


def _note_inapplicable(planner: str, ignored: list[str], from_o: set[str]) -> None:
    """One line on stderr naming the given flags the chosen planner ignores."""
    if ignored:
        flags = ", ".join(f"-o {k}" if k in from_o else _flag(k) for k in ignored)
        err_console.print(f"note: {flags} do(es) not apply to planner '{planner}'", highlight=False)


def _with_replay_mode(backend: str, loose: bool) -> str:
    """Replay backends take their matching mode in the spec; `--replay-loose` adds it."""
    if not loose:
        return backend
    if not backend.lower().startswith("replay:"):
        raise BadInputError("--replay-loose only applies to --backend replay:RUN_DIR")
    return backend + ("&" if "?" in backend else "?") + "loose"


def _run_with_view(
    spec: EpisodeSpec, *, quiet: bool, json_output: bool, later: list[Callable[[], None]]
) -> dict[str, Any]:
    # deferred: pydantic and yaml (about 0.15 s, via the runner), not for `llmnav --help`
    from llmnav.planners.base import NullView
    from llmnav.reporting.live import LiveView, ProgressView
    from llmnav.runs.runner import run_episode

    if json_output:
        return run_episode(spec, view=NullView(), later=later)
    view = ProgressView(console, spec.options.max_iterations) if quiet else LiveView(console, spec)
    with view:
        return run_episode(spec, view=view, later=later)
