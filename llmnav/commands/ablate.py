"""`llmnav ablate`: run a grid of conditions over tasks, start poses and trials, then print the tables."""

from __future__ import annotations

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
    parse_option_pairs,
    path_option,
    print_table,
)
from llmnav.commands.planner_flags import GIVEN, SweepFlags, declared_flags
from llmnav.errors import BadInputError

if TYPE_CHECKING:
    from llmnav.ablate import Ablation, ManifestEntry

_LIST = "comma-separated"
EXIT_EPISODE_ERRORS = 1  # the sweep ran, but some episodes ended in an error (the manifest lists them)


@cli_errors
def ablate(
    ctx: typer.Context,
    scenario: Annotated[
        str | None,
        typer.Option("--scenario", help="Scenario name or file; a suite: a folder of files, or generated:KIND:N."),
    ] = None,
    tasks: Annotated[str | None, typer.Option("--tasks", help=f"Task ids ({_LIST}) or 'all'.")] = None,
    poses: Annotated[str | None, typer.Option("--poses", help="Start poses: 1-5, 1,3 or all.")] = None,
    trials: Annotated[int | None, typer.Option("--trials", min=1, help="Trials per task, pose and condition.")] = None,
    seed: Annotated[int | None, typer.Option("--seed", help="Base seed (episode seeds derive from it).")] = None,
    lidar_sectors: Annotated[str | None, typer.Option("--lidar-sectors", help=f"e.g. 3,5,8 ({_LIST}).")] = None,
    sensing: Annotated[str | None, typer.Option("--sensing", help=f"e.g. lidar+image,image ({_LIST}).")] = None,
    backend: Annotated[str | None, typer.Option("--backend", help=f"Backend specs ({_LIST}).")] = None,
    decide: Annotated[str | None, typer.Option("--decide", help=f"Choices: score, generate, auto ({_LIST}).")] = None,
    option: Annotated[
        list[str] | None,
        typer.Option("-o", "--option", help=f"KEY=V1,V2: any planner option as a factor ({_LIST}; repeatable)."),
    ] = None,
    planner: Annotated[str | None, typer.Option("--planner", help=f"Planners ({_LIST}).")] = None,
    wording: Annotated[
        str | None, typer.Option("--wording", help=f"Task wordings: bundled, paraphrase:K ({_LIST}).")
    ] = None,
    paraphrases: Annotated[
        bool, typer.Option("--paraphrases", help="Wording as a factor: bundled and paraphrases 1-3.")
    ] = False,
    grid: Annotated[Path | None, typer.Option("--grid", help="Grid YAML file (flags override its keys).")] = None,
    name: Annotated[
        str | None, typer.Option("--name", help="Ablation name (default from scenario and factors).")
    ] = None,
    out: Annotated[str | None, typer.Option("--out", help="Ablation folder (default ablations/<name>).")] = None,
    workers: Annotated[
        int, typer.Option("--workers", min=1, help="Parallel worker processes (at most the usable cores).")
    ] = 1,
    model_layout: Annotated[
        str,
        typer.Option(
            "--model-layout",
            help="With the local model and several workers: 'shared' (one loaded model, a slot per worker), "
            "'per-worker' (a copy in each), or 'auto' (the one measured faster).",
        ),
    ] = "auto",
    max_episodes: Annotated[
        int | None,
        typer.Option("--max-episodes", min=1, help="Refuse a grid of more episodes than this (default 20000)."),
    ] = None,
    ray: Annotated[
        str | None,
        typer.Option(
            "--ray",
            help="Ray tasks: 'local' (a private Ray on loopback), or a cluster: HOST:PORT, ray://HOST:PORT, auto.",
        ),
    ] = None,
    dry_run: Annotated[bool, typer.Option("--dry-run", help="List the episodes and stop.")] = False,
    drop_images: DropImagesOption = False,
    cache: CacheOption = None,
    prices: PricesOption = None,
    max_cost: Annotated[
        float | None,
        typer.Option(
            "--max-cost",
            help="US dollars: refuse a sweep estimated above this, stop one that reaches it (resumable).",
        ),
    ] = None,
    episode_tokens: Annotated[
        str | None,
        typer.Option(
            "--episode-tokens",
            help="PROMPT,COMPLETION tokens one episode is assumed to use, for --max-cost's estimate "
            "(default: the mean cost of the episodes already finished).",
        ),
    ] = None,
    plots: Annotated[
        bool, typer.Option("--plots", help="Write each run's trajectory.png (slower; off by default).")
    ] = False,
    view_page: Annotated[
        bool, typer.Option("--view", help="Write the sweep's HTML page (and its runs' pages) at the end.")
    ] = False,
    export: Annotated[
        str | None, typer.Option("--export", help="At the end, also write each run as: mcap (into FOLDER/mcap).")
    ] = None,
) -> None:
    """Run an ablation grid (resumable: run it again to finish it), then print the tables by factor."""
    from llmnav import ablate as lib

    planner_flags = declared_flags(sweep=True)  # a planner's own flags: a factor each, or one fixed value
    factors = {f.key for f in planner_flags if f.sweep == "factor"}
    fixed = {f.key for f in planner_flags if f.sweep == "fixed"}
    data: dict[str, Any] = lib.load_grid_file(grid) if grid is not None else {}
    flags: dict[str, Any] = {"scenario": scenario, "trials": trials, "seed": seed, "name": name}
    if tasks is not None:
        flags["tasks"] = "all" if tasks.strip().lower() == "all" else lib.split_list(tasks)
    if poses is not None:
        flags["poses"] = lib.parse_poses(poses)
    for key, value in (
        ("lidar_sectors", lidar_sectors), ("sensing", sensing), ("backend", backend), ("planner", planner),
        ("wording", wording), ("decide", decide),
        *((key, value) for key, value in ctx.meta.get(GIVEN, {}).items() if key in factors),
    ):  # fmt: skip
        if value is not None:
            flags[key] = lib.split_list(value)
    for key, value in parse_option_pairs(option).items():
        if key in lib.GridSpec.model_fields:
            raise BadInputError(f"-o {key}: give it with --{key.replace('_', '-')}")
        flags[key] = lib.split_list(value)
    if paraphrases:
        if wording is not None:
            raise BadInputError("give --paraphrases or --wording, not both")
        flags["wording"] = ["bundled", *(f"paraphrase:{k}" for k in range(1, 4))]
    data.update({k: v for k, v in flags.items() if v is not None})
    if drop_images:
        data["options"] = {**(data.get("options") or {}), "drop_images": True}
    once = {k: v for k, v in ctx.meta.get(GIVEN, {}).items() if k in fixed}
    if once:
        data["options"] = {**data.get("options", {}), **once}
    if export not in (None, "mcap"):
        raise BadInputError(f"--export {export!r}: the one format is mcap")
    spec = lib.grid_from_mapping(data, str(grid) if grid is not None else "ablate")
    root = path_option(out, "--out") or Path("ablations") / spec.default_name().replace(":", "-")
    limit = max_episodes or lib.MAX_EPISODES
    from llmnav.buildings.suite import is_suite, suite_files

    if is_suite(spec.scenario):  # one ablation per building, each in its own folder under root
        files = suite_files(spec.scenario, root / "scenarios")
        ablations = [lib.plan(spec.model_copy(update={"scenario": str(f)}), root / f.stem, limit) for f in files]
    else:
        ablations = [lib.plan(spec, root, limit)]  # the size is checked before the grid is built
    if dry_run:
        for ablation in ablations:
            _print_plan(ablation)
        _note_inapplicable(spec)
        return
    if model_layout not in lib.LAYOUTS:
        raise BadInputError(f"--model-layout {model_layout!r}: choose one of {', '.join(lib.LAYOUTS)}")
    workers = _usable_workers(workers)
    cache_dir = _absolute(path_option(cache, "--cache"))
    prices_file = _absolute(path_option(prices, "--prices"))
    budget = _budget(max_cost, episode_tokens, prices_file)
    for ablation in ablations:
        with _progress() as progress:
            lib.run(
                ablation,
                workers=workers,
                ray_address=ray,
                plots=plots,
                layout=model_layout,
                on_layout=_say_layout,
                on_start=lambda *_, ab=ablation: progress.start(ab),
                on_result=progress.advance,
                cache_dir=cache_dir,
                prices=prices_file,
                budget=budget,
            )
        _print_results(ablation)
        if export == "mcap":
            from llmnav.ros.export import export_sweep

            folder = ablation.root / "mcap"
            written = export_sweep(ablation.root, folder)
            console.print(f"{len(written)} MCAP file(s) in {esc(str(folder))}", highlight=False, soft_wrap=True)
        if view_page:
            from llmnav.view.api import write_view

            console.print(f"page: {esc(str(write_view(ablation.root).page))}", highlight=False, soft_wrap=True)
    if len(ablations) > 1:
        _print_suite(ablations)
    _note_inapplicable(spec)  # after the work: a failure stays one error line
    errors = ablation.counts()[2]
    if errors:  # a sweep with failed episodes is not a clean result, whatever the tables show
        raise typer.Exit(EXIT_EPISODE_ERRORS)


ablate.command_class = SweepFlags  # type: ignore[attr-defined]  # the planners' flags join ablate's


def _budget(max_cost: float | None, episode_tokens: str | None, prices: Path | None) -> Any:
    """The sweep's `Budget` for `--max-cost` (None without it); the price table is read and checked here."""
    from llmnav.ablate.budget import Budget, check_limit, parse_episode_tokens
    from llmnav.backends.prices import load_prices

    table = load_prices(prices)  # a bad price file is refused before any episode, with or without a limit
    if max_cost is None:
        if episode_tokens is not None:
            raise BadInputError("--episode-tokens only applies with --max-cost")
        return None
    tokens = parse_episode_tokens(episode_tokens) if episode_tokens is not None else None
    return Budget(check_limit(max_cost), table, tokens)


def _print_suite(ablations: list[Ablation]) -> None:
    """One line for the whole suite: episodes done and successes over every building."""
    counts = [ablation.counts() for ablation in ablations]
    done, successes, errors = (sum(c[k] for c in counts) for k in range(3))
    total = sum(ablation.size for ablation in ablations)
    console.print(
        f"suite of {len(ablations)} scenarios: {done}/{total} episodes done, {successes} successes, {errors} error(s)",
        highlight=False,
        soft_wrap=True,
    )


def _say_layout(layout: Any) -> None:
    """One line on stderr when the sweep has a model layout to choose (several workers, the local model)."""
    if layout.model in ("shared", "per-worker"):
        err_console.print(esc(layout.describe()), highlight=False, soft_wrap=True)


def _usable_workers(workers: int) -> int:
    """`workers`, capped at the cores this process may run on (more processes only share them)."""
    import os

    try:
        cores = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # not Linux
        cores = os.cpu_count() or 1
    if workers > cores:
        err_console.print(f"note: --workers {workers} capped at {cores}, the usable cores", highlight=False)
        return cores
    return workers


def _note_inapplicable(spec: Any) -> None:
    """One line on stderr per planner that ignores some of the grid's factors or fixed options."""
    from llmnav.planners.base import inapplicable_options

    given = set(spec.options) | set(spec.option_factors())
    for planner in spec.planners():
        unused = inapplicable_options(planner, given)
        if unused:
            err_console.print(f"note: {', '.join(unused)} do(es) not apply to planner '{planner}'", highlight=False)


def _print_plan(ablation: Ablation) -> None:
    from rich.table import Table

    from llmnav.ablate import describe_episodes

    table = Table(title=esc(f"{ablation.grid.default_name()}: {ablation.size} episodes → {ablation.root}"))
    for column in ("Key", "Task", "Pose", "Trial", "Seed", "Backend"):
        table.add_column(column)
    for row in describe_episodes(ablation.episodes):
        table.add_row(*(esc(cell) for cell in row))
    print_table(table)
    factors = ablation.grid.factors()
    detail = ", ".join(f"{k}: {len(v)}" for k, v in factors.items()) or "no factors"
    console.print(esc(f"{ablation.size} episodes ({detail}; trials: {ablation.grid.trials})"), highlight=False)


class _progress:
    """A rich progress bar with ETA and a running success count (a context manager)."""

    def __init__(self) -> None:
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

        self.bar = Progress(
            TextColumn("[bold]ablate[/]"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("success {task.fields[successes]}/{task.fields[finished]}"),
            TextColumn("errors {task.fields[errors]}"),
            TimeRemainingColumn(),
            console=console,
        )
        self.task_id: Any = None

    def __enter__(self) -> _progress:
        self.bar.__enter__()
        return self

    def __exit__(self, *exc: object) -> None:
        self.bar.__exit__(None, None, None)

    def start(self, ablation: Ablation) -> None:
        """Bar at the episodes already finished by an earlier run; name the folders set aside."""
        for name, why in ablation.kept:
            err_console.print(
                f"kept {esc(ablation.root / name)} ({esc(why)}); its episode runs again in a new folder",
                highlight=False,
                soft_wrap=True,
            )
        done, successes, _ = ablation.counts()
        self.task_id = self.bar.add_task(
            "ablate", total=ablation.size, completed=done, successes=successes, finished=done, errors=0
        )

    def advance(self, entry: ManifestEntry, ablation: Ablation) -> None:
        """One more episode settled."""
        done, successes, errors = ablation.counts()
        self.bar.update(self.task_id, advance=1, finished=done, successes=successes, errors=errors)


def _absolute(path: Path | None) -> Path | None:
    """A path the workers (and Ray tasks, which may start elsewhere) find as this process does."""
    return path.absolute() if path is not None else None


def _cost_line(ablation: Ablation) -> str:
    """ ", cost 0.0123 USD" over the finished episodes (", cost unknown for N" when some have none)."""
    done = [e for e in ablation.entries.values() if e.status == "done"]
    unknown = sum(1 for e in done if e.cost_usd is None)
    total = sum(e.cost_usd or 0.0 for e in done)
    return f", cost {total:.4f} USD" + (f" (+ unknown for {unknown} episode(s))" if unknown else "")


def _print_results(ablation: Ablation) -> None:
    from llmnav.ablate import results_runs, table_keys
    from llmnav.reporting.tables import print_tables
    from llmnav.scoring.tables import build_tables

    runs = results_runs(ablation)
    errors = [e for e in ablation.entries.values() if e.status == "error"]
    if runs:
        print_tables(console, build_tables(runs, table_keys(ablation)))
    console.print(
        f"{len(runs)}/{ablation.size} episodes done, {len(errors)} error(s){_cost_line(ablation)}; "
        f"manifest: {esc(ablation.root / 'manifest.json')}",
        highlight=False,
        soft_wrap=True,
    )
    for entry in errors[:5]:
        console.print(f"[red]error[/] {esc(entry.key)}: {esc(entry.error)}", highlight=False, soft_wrap=True)
