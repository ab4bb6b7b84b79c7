"""`llmnav scenarios`: list the bundled scenarios, show one scenario's tasks and plot its top view."""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.table import Table

from llmnav.commands.common import (
    check_output_path,
    cli_errors,
    console,
    err_console,
    esc,
    listing_format,
    path_option,
    plot_option,
    print_listing,
    print_table,
)
from llmnav.core.safefiles import write_text
from llmnav.errors import BadInputError, one_line

if TYPE_CHECKING:
    from llmnav.world.scenario import Scenario, Task

app = typer.Typer(
    help="List the bundled scenarios, show one (tasks, start poses, top-view plot), generate or check one, "
    "import or export a nav2 map.",
    no_args_is_help=False,
)


def _size(scenario: Scenario) -> str:
    """The world's extent as 'W m x H m'."""
    bx, by = scenario.bounds.x, scenario.bounds.y
    return f"{bx[1] - bx[0]:.1f} m x {by[1] - by[0]:.1f} m"


def _targets(scenario: Scenario, task: Task) -> str:
    """Acceptable targets as 'ID (label)' or '(x, y)'."""
    parts = []
    for target in task.targets:
        if target.object is not None:
            parts.append(f"{target.object} ({scenario.object(target.object).label})")
        else:
            assert target.point is not None
            parts.append(f"point ({target.point[0]:g}, {target.point[1]:g})")
    return ", ".join(parts) or "-"


FORMAT_HELP = "table | tsv | json (tsv and json: only data on stdout)."


@app.callback(invoke_without_command=True)
@cli_errors
def scenarios(
    ctx: typer.Context,
    output_format: Annotated[str, typer.Option("--format", help=FORMAT_HELP)] = "table",
) -> None:
    """List the bundled scenarios (the default when no subcommand is given)."""
    if ctx.invoked_subcommand is None:
        list_command(output_format)
    elif output_format != "table":
        raise BadInputError(f"--format goes after the subcommand: scenarios {ctx.invoked_subcommand} --format ...")


@app.command("list")
@cli_errors
def list_command(output_format: Annotated[str, typer.Option("--format", help=FORMAT_HELP)] = "table") -> None:
    """Table of the bundled scenarios: name, robot, size, objects, tasks."""
    output_format = listing_format(output_format)
    table = Table(title="Bundled scenarios")
    for column in ("name", "robot", "size", "objects", "tasks", "description"):
        table.add_column(column, justify="right" if column in ("objects", "tasks") else "left")
    # deferred: pydantic and yaml (about 0.15 s, via llmnav.world.scenario), not for `llmnav --help`
    from llmnav.world.scenario import list_scenarios, load_scenario

    records = []
    for name in list_scenarios():
        scenario = load_scenario(name)
        table.add_row(
            esc(name),
            esc(scenario.robot),
            _size(scenario),
            str(len(scenario.objects)),
            str(len(scenario.tasks)),
            esc(scenario.description),
        )
        (x0, x1), (y0, y1) = scenario.bounds.x, scenario.bounds.y
        records.append({
            "name": name,
            "robot": scenario.robot,
            "width_m": round(x1 - x0, 3),
            "depth_m": round(y1 - y0, 3),
            "objects": len(scenario.objects),
            "tasks": len(scenario.tasks),
            "description": scenario.description,
        })  # fmt: skip
    print_listing(output_format, records, table)


@app.command("show")
@cli_errors
def show(
    name: Annotated[str, typer.Argument(help="Bundled scenario name or path to a scenario YAML file.")],
    plot: Annotated[str | None, typer.Option("--plot", help="Write a top view PNG to this file.")] = None,
    task: Annotated[str | None, typer.Option("--task", help="Only this task (id), also in the plot.")] = None,
) -> None:
    """A scenario's tasks (id, kind, difficulty, text, targets, start poses); optionally its top view."""
    # deferred: pydantic and yaml (about 0.15 s, via llmnav.world.scenario), not for `llmnav --help`
    from llmnav.world.scenario import load_scenario

    plot_path = plot_option(plot)
    scenario = load_scenario(name)
    chosen: Task | None = None
    if task is not None:
        try:
            chosen = scenario.task(task)
        except KeyError:
            known = ", ".join([t.id for t in scenario.tasks] + [r.id for r in scenario.routes]) or "none"
            raise BadInputError(f"scenario '{scenario.name}' has no task '{task}' (tasks: {known})") from None
    console.print(
        f"[bold]{esc(scenario.name)}[/] ({esc(scenario.robot)}, {_size(scenario)}, "
        f"{len(scenario.objects)} objects)" + (f": {esc(scenario.description)}" if scenario.description else ""),
        highlight=False,
        soft_wrap=True,
    )
    table = Table()
    for column in ("id", "kind", "difficulty", "text", "targets"):
        table.add_column(column, no_wrap=column in ("id", "kind"))
    table.add_column("start poses x, y @ yaw", no_wrap=True)
    # routes (legs driven one after another, `--task-id ID`) are listed as the tasks they run as
    for t in [chosen] if chosen is not None else [*scenario.tasks, *(r.as_task() for r in scenario.routes)]:
        starts = "\n".join(f"{s.x:g}, {s.y:g} @ {s.yaw_deg:g}°" for s in scenario.start_poses(t))
        table.add_row(esc(t.id), t.kind, t.difficulty, esc(t.text), esc(_targets(scenario, t)), starts)
    print_table(table)
    if plot_path is not None:
        # deferred: the top view (matplotlib when drawing) loads only with --plot
        from llmnav.reporting.topview import plot_scenario

        written = plot_scenario(scenario, plot_path, task=chosen)
        console.print(f"top view written to {esc(written)}", highlight=False, soft_wrap=True)


def _size_option(text: str | None) -> tuple[float, float] | None:
    """`--size 12x9` as metres (x, y)."""
    if text is None:
        return None
    parts = text.lower().replace(" ", "").split("x")
    try:
        if len(parts) != 2:
            raise ValueError
        width, depth = float(parts[0]), float(parts[1])
    except ValueError:
        raise BadInputError(f"--size {text!r}: expected WIDTHxDEPTH in metres, e.g. 12x9") from None
    if not (math.isfinite(width) and math.isfinite(depth)):
        raise BadInputError(f"--size {text!r}: sides must be finite numbers")
    return (width, depth)


@app.command("generate")
@cli_errors
def generate_command(
    kind: Annotated[str, typer.Option("--kind", help="flat, office or warehouse.")],
    seed: Annotated[int, typer.Option("--seed", help="Seed: the same seed writes the same file, byte for byte.")],
    out: Annotated[str, typer.Option("-o", "--out", help="Scenario file to write (.yaml); with --count a folder.")],
    rooms: Annotated[int | None, typer.Option("--rooms", help="Number of rooms (default: the kind's).")] = None,
    size: Annotated[str | None, typer.Option("--size", help="Outer size WxD in metres, e.g. 12x9.")] = None,
    starts: Annotated[int, typer.Option("--starts", help="Start poses per task (at most).")] = 3,
    robot: Annotated[str | None, typer.Option("--robot", help="pr2 or burger (default: the kind's).")] = None,
    count: Annotated[
        int | None, typer.Option("--count", help="A suite: this many buildings, seeds SEED.., into the folder -o.")
    ] = None,
) -> None:
    """Generate a building (rooms, doorways, furniture by room type, tasks with checked start poses)."""
    # deferred: the generator brings numpy and scipy (about 0.4 s), not for `llmnav --help`
    from llmnav.buildings.generate import Request, generate_suite

    path = path_option(out, "--out")
    assert path is not None
    if count is None:
        if path.suffix.lower() not in (".yaml", ".yml"):
            raise BadInputError(f"--out {out}: a scenario file ends in .yaml")
    elif path.exists() and not path.is_dir():
        raise BadInputError(f"--out {out}: with --count, a folder to write the suite into")
    request = Request(kind, seed, rooms, _size_option(size), starts, robot)
    buildings = generate_suite(request, 1 if count is None else count)  # every file is made before any is written
    targets = [path] if count is None else [path / f"{b.scenario.name}.yaml" for b in buildings]
    try:
        if count is not None:
            path.mkdir(parents=True, exist_ok=True)
        for target, building in zip(targets, buildings, strict=True):
            write_text(target, building.text)
    except OSError as err:
        raise BadInputError(f"--out {out}: cannot write: {err.strerror or err}") from None
    for target, building in zip(targets, buildings, strict=True):
        scenario = building.scenario
        err_console.print(
            f"wrote {esc(str(target))}: {esc(scenario.description)} {len(scenario.tasks)} tasks.",
            highlight=False,
            soft_wrap=True,
        )


@app.command("check")
@cli_errors
def check_command(
    files: Annotated[list[str], typer.Argument(help="Scenario files, or folders of them (*.yaml).")],
) -> None:
    """Check start-pose clearance, target reachability for the robot's footprint and hidden targets."""
    # deferred: the checker brings numpy and scipy (about 0.4 s), not for `llmnav --help`
    from llmnav.buildings.check import check_file

    failed = False
    expanded: list[str] = []
    for name in files:
        folder = Path(name)
        if folder.is_dir():
            inside = sorted(str(p) for p in folder.glob("*.yaml"))
            if not inside:
                err_console.print(
                    f"{esc(name)}: a folder without scenario files (*.yaml)", highlight=False, soft_wrap=True
                )
                failed = True
            expanded += inside
        else:
            expanded.append(name)
    for name in expanded:
        problems = check_file(Path(name))
        for line in problems:
            err_console.print(esc(one_line(line)), highlight=False, soft_wrap=True)
        if problems:
            failed = True
        else:
            console.print(f"{esc(name)}: ok", highlight=False, soft_wrap=True)
    if failed:
        raise typer.Exit(2)


@app.command("import-map")
@cli_errors
def import_map(
    map_yaml: Annotated[Path, typer.Argument(help="A nav2 map_server map: YAML naming a PGM or PNG image.")],
    out: Annotated[Path, typer.Option("-o", "--out", help="The world (scenario YAML) to write.")],
    objects: Annotated[
        Path | None,
        typer.Option("--objects", help="Overlay YAML: labelled objects (id, label, position, size), tasks, start."),
    ] = None,
    robot: Annotated[str, typer.Option("--robot", help="Robot model: burger | pr2.")] = "burger",
    tasks: Annotated[int, typer.Option("--tasks", help="Point tasks to draw on the free space (seeded).")] = 5,
    seed: Annotated[int, typer.Option("--seed", help="Seed of the drawn tasks.")] = 0,
) -> None:
    """Turn a nav2 map (map.yaml + image) into a world: occupied and unknown cells become merged wall boxes."""
    # deferred: the map import brings numpy, pydantic and yaml (about 0.25 s), not for `llmnav --help`
    from llmnav.ros.mapimport import import_map as build
    from llmnav.ros.mapimport import write_world

    if out.suffix.lower() not in (".yaml", ".yml"):
        raise BadInputError(f"-o {out}: give a file name ending in .yaml")
    if out.exists() or out.is_symlink():
        raise BadInputError(f"-o {out}: already exists; choose another file (nothing is overwritten)")
    check_output_path(out, "-o", [map_yaml, *([objects] if objects else [])])
    result = build(map_yaml, overlay=objects, robot=robot, tasks=tasks, seed=seed)
    written = write_world(result, out, map_yaml)
    width, height = result.size_px
    console.print(
        f"wrote {esc(str(written))}: {width} x {height} cells, {result.walls} wall boxes, "
        f"{len(result.scenario.objects)} objects, {len(result.scenario.tasks)} tasks",
        highlight=False,
        soft_wrap=True,
    )


@app.command("export-map")
@cli_errors
def export_map(
    world: Annotated[str, typer.Argument(help="Bundled scenario name or path to a scenario YAML file.")],
    out: Annotated[Path, typer.Option("-o", "--out", help="The nav2 map YAML to write (the PGM goes beside it).")],
    resolution: Annotated[float, typer.Option("--resolution", help="Cell side [m].")] = 0.05,
) -> None:
    """Write a world as a nav2 map_server map (YAML + PGM): solid shapes occupied, the rest free."""
    # deferred: the map export brings numpy, pydantic and yaml (about 0.25 s), not for `llmnav --help`
    from llmnav.ros.mapexport import export_map as write_map
    from llmnav.world.scenario import load_scenario

    if out.suffix.lower() not in (".yaml", ".yml"):
        raise BadInputError(f"-o {out}: give a file name ending in .yaml")
    check_output_path(out, "-o")
    written, image = write_map(load_scenario(world), out, resolution)
    console.print(f"wrote {esc(str(written))} and {esc(image.name)}", highlight=False, soft_wrap=True)
