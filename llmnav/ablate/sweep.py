"""Running an ablation: settle which episodes are finished, run the others, rewrite the manifest after each."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import closing, contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from llmnav.ablate.budget import Budget
from llmnav.ablate.executors import Runner, default_runner, execute_episode, run_pool
from llmnav.ablate.grid import Episode, GridSpec
from llmnav.ablate.layout import Layout, choose
from llmnav.ablate.manifest import MANIFEST_FILE, Ablation, ManifestEntry, without_credentials
from llmnav.ablate.resume import locate, set_aside
from llmnav.core.safefiles import SUMMARY_LIMIT, UnsafeFileError, is_our_page, loads, read_bytes
from llmnav.errors import BadInputError
from llmnav.runs.locking import LOCK_FILE, FolderLock
from llmnav.runs.runlog import RUN_FILE

ProgressCallback = Callable[[ManifestEntry, "Ablation"], None]


def run(
    ablation: Ablation,
    *,
    workers: int = 1,
    ray_address: str | None = None,
    runner: Runner | None = None,
    plots: bool = False,
    layout: str = "auto",
    on_layout: Callable[[Layout], None] | None = None,
    on_start: Callable[[int, int, int], None] | None = None,
    on_result: ProgressCallback | None = None,
    cache_dir: Path | None = None,
    prices: Path | None = None,
    budget: Budget | None = None,
) -> Ablation:
    """Run every unfinished episode; the manifest is rewritten after each one.

    `plots` writes each run's trajectory.png; off by default: drawing it cost more than a scripted
    episode itself, and the tables need only the logs and summaries.

    `layout` ("auto", "shared", "per-worker") says where the local model runs with several workers (see
    `llmnav.ablate.layout`); `on_layout(layout)` is told the one taken before any episode runs.
    `on_start(total, already_done, successes)` is called once before any episode runs, `on_result` after
    each. `runner` (default `llmnav.runs.runner.run_episode`) must be picklable for `workers > 1` and Ray.
    `cache_dir` and `prices` go to every episode (`EpisodeSpec`); `budget` refuses a sweep estimated above
    its limit and stops one that reaches it (`llmnav.ablate.budget`).
    """
    default = runner is None
    runner = runner or default_runner()
    root = ablation.root
    check_out_folder(root, ablation)
    # One sweep per folder: a second process (same grid or not) stops here with the holder's pid.
    with FolderLock(root, "ablation folder"):
        check_out_folder(root, ablation)  # again: another sweep may have written it while we waited
        settings = _Settings(
            workers, ray_address, plots, layout, default, on_layout, on_start, on_result, cache_dir, prices, budget
        )
        _run_locked(ablation, runner, settings)
    return ablation


@dataclass(frozen=True)
class _Settings:
    """How `run` was asked to run the sweep."""

    workers: int
    ray_address: str | None
    plots: bool
    layout: str
    default_runner: bool  # the episodes build the backends their specs name
    on_layout: Callable[[Layout], None] | None
    on_start: Callable[[int, int, int], None] | None
    on_result: ProgressCallback | None
    cache_dir: Path | None = None
    prices: Path | None = None
    budget: Budget | None = None


def check_out_folder(root: Path, ablation: Ablation) -> None:
    """Refuse an --out that is not this ablation's folder.

    That is: a run folder, a folder of other files, or the folder of a different grid (whose manifest
    would be overwritten).
    """
    if not root.exists():
        for parent in root.absolute().parents:
            if (parent / RUN_FILE).exists():
                raise BadInputError(f"--out {root}: inside the run folder {parent}; choose another folder")
        return
    if not root.is_dir():
        raise BadInputError(f"--out {root}: not a folder")
    if (root / RUN_FILE).exists() or any((p / RUN_FILE).exists() for p in root.absolute().parents):
        raise BadInputError(f"--out {root}: a run folder, not an ablation folder; choose another folder")
    foreign = [p.name for p in root.iterdir() if not _ablation_entry(p)]
    if foreign:
        raise BadInputError(
            f"--out {root}: holds files that are not an ablation's ({', '.join(sorted(foreign)[:3])}); "
            "choose an empty or new folder"
        )
    manifest_path = root / MANIFEST_FILE
    if not manifest_path.exists():  # run folders without their manifest: resume finds them by condition
        return
    try:
        old = loads(read_bytes(manifest_path, limit=SUMMARY_LIMIT, root=root))["grid"]
        old_grid = GridSpec.model_validate(old)
    except (OSError, UnsafeFileError, UnicodeDecodeError, ValueError, KeyError, TypeError):
        raise BadInputError(f"--out {root}: {MANIFEST_FILE} is damaged; move it away to run into this folder") from None
    new = without_credentials(ablation.grid.model_dump(mode="json", exclude={"name"}))  # as the manifest holds it
    before = old_grid.model_dump(mode="json", exclude={"name"})
    changed = [k for k in new if new[k] != before.get(k)]
    if changed:
        key = changed[0]
        raise BadInputError(
            f"--out {root} holds another grid ({key}: {before.get(key)!r} there, {new[key]!r} now); "
            "choose another --out (results are never replaced)"
        )


def _ablation_entry(path: Path) -> bool:
    """Whether `path` is something llmnav writes in an ablation folder: lock, manifest, run folder, view page."""
    if path.name in (LOCK_FILE, MANIFEST_FILE, MANIFEST_FILE + ".tmp"):
        return True
    if path.suffix == ".html" and is_our_page(path):  # `llmnav view ABL` or `ablate --view`
        return True
    return path.is_dir() and any((path / name).exists() for name in (RUN_FILE, RUN_FILE + ".tmp", LOCK_FILE))


def _run_locked(ablation: Ablation, runner: Runner, settings: _Settings) -> None:
    root = ablation.root
    pending: list[tuple[Episode, str]] = []
    ablation.kept = []
    located = []
    for ep in ablation.episodes:
        entry = ablation.entries[ep.key]
        found = locate(ep, root)
        entry.kept = [*found.earlier, *(f"{name}: {why}" for name, why in found.kept)]
        ablation.kept += [(name, why) for name, why in found.kept]
        if found.summary is not None:
            entry.dir = found.dir_name
            entry.record(found.summary)
            continue
        located.append((ep, found))
    budget = settings.budget
    if budget is not None:  # refused before any folder is set aside or the manifest rewritten
        budget.check_start([ep for ep, _ in located], ablation)
    for ep, found in located:
        set_aside(root, found.kept, ep.key, found.dir_name)
        ablation.entries[ep.key].reset(found.dir_name)
        pending.append((ep, found.dir_name))
    workers = settings.workers if len(pending) > 1 else 1
    layout = choose(
        _model_backends([ep for ep, _ in pending]),
        workers,
        requested=settings.layout,
        ray=settings.ray_address is not None,
        runs_backends=settings.default_runner,
    )
    ablation.layout = layout if pending else _recorded_layout(root)  # nothing to run: the manifest stays
    ablation.write_manifest()
    if settings.on_layout is not None and pending:
        settings.on_layout(layout)
    if settings.on_start is not None:
        done, successes, _ = ablation.counts()
        settings.on_start(ablation.size, done, successes)

    def settle(ep: Episode, result: tuple[dict[str, Any] | None, str | None, bool]) -> None:
        summary, error, fatal = result
        entry = ablation.entries[ep.key]
        if summary is not None:
            entry.record(summary)
        else:
            entry.status, entry.error = "error", error
        ablation.write_manifest()
        if settings.on_result is not None:
            settings.on_result(entry, ablation)
        if fatal:
            raise BadInputError(f"episode {ep.key}: {error}")
        settled.add(ep.key)
        why = budget.add(summary) if budget is not None else None
        if why is not None and budget is not None and len(settled) < len(specs):
            raise budget.stop(why, len(specs) - len(settled))

    extra = {"cache_dir": settings.cache_dir, "prices": settings.prices}
    specs = [
        (ep, ep.spec(root, ablation.grid.scenario, plots=settings.plots, dir_name=name).model_copy(update=extra))
        for ep, name in pending
    ]
    settled: set[str] = set()
    if settings.ray_address is not None:
        from llmnav.ablate.ray_tasks import run_ray

        for ep, result in run_ray(runner, specs, settings.ray_address):
            settle(ep, result)
    elif workers > 1:
        with _model_for(layout) as env, closing(run_pool(runner, specs, workers, env)) as results:
            for ep, result in results:  # the pool is shut down (running episodes end) before the model is
                settle(ep, result)
    else:
        for ep, spec in specs:
            settle(ep, execute_episode(runner, spec))


def _model_backends(episodes: list[Episode]) -> list[str]:
    """The backend specs of the episodes whose planner asks a model (the oracle and frontier baselines do not)."""
    from llmnav.planners.base import planner_class

    asks = {name: planner_class(name).needs_backend for name in {ep.options.planner for ep in episodes}}
    return sorted({ep.backend for ep in episodes if asks[ep.options.planner]})


def _recorded_layout(root: Path) -> Layout | None:
    """The layout the folder's manifest records (None when it records none, or cannot be read)."""
    try:
        recorded = loads(read_bytes(root / MANIFEST_FILE, limit=SUMMARY_LIMIT, root=root)).get("layout")
        return Layout(**recorded) if isinstance(recorded, dict) else None
    except (OSError, UnsafeFileError, UnicodeDecodeError, ValueError, TypeError, AttributeError):
        return None


@contextmanager
def _model_for(layout: Layout) -> Iterator[dict[str, str]]:
    """The workers' environment: empty, or pointing at the shared model server it starts and stops."""
    if not layout.shared:
        yield {}
        return
    from llmnav.backends.local import DEFAULT_N_CTX
    from llmnav.serve.shared import SharedModel

    model = SharedModel(Path(layout.model_path or ""), slots=layout.slots, n_ctx=DEFAULT_N_CTX, threads=layout.threads)
    with model as served:
        yield served.env()
