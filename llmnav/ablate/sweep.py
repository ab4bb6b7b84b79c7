"""Running an ablation: settle which episodes are finished, run the others, rewrite the manifest after each."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from llmnav.ablate.executors import Runner, default_runner, execute_episode, run_pool
from llmnav.ablate.grid import Episode, GridSpec
from llmnav.ablate.manifest import MANIFEST_FILE, Ablation, ManifestEntry, without_credentials
from llmnav.ablate.resume import locate, set_aside
from llmnav.errors import BadInputError
from llmnav.locking import LOCK_FILE, FolderLock
from llmnav.runlog import RUN_FILE
from llmnav.safefiles import SUMMARY_LIMIT, UnsafeFileError, is_our_page, loads, read_bytes

ProgressCallback = Callable[[ManifestEntry, "Ablation"], None]


def run(
    ablation: Ablation,
    *,
    workers: int = 1,
    ray_address: str | None = None,
    runner: Runner | None = None,
    plots: bool = False,
    on_start: Callable[[int, int, int], None] | None = None,
    on_result: ProgressCallback | None = None,
) -> Ablation:
    """Run every unfinished episode; the manifest is rewritten after each one.

    `plots` writes each run's trajectory.png; off by default: drawing it cost more than a scripted
    episode itself, and the tables need only the logs and summaries.

    `on_start(total, already_done, successes)` is called once before any episode runs, `on_result` after
    each. `runner` (default `llmnav.runner.run_episode`) must be picklable for `workers > 1` and Ray.
    """
    runner = runner or default_runner()
    root = ablation.root
    check_out_folder(root, ablation)
    # One sweep per folder: a second process (same grid or not) stops here with the holder's pid.
    with FolderLock(root, "ablation folder"):
        check_out_folder(root, ablation)  # again: another sweep may have written it while we waited
        _run_locked(ablation, runner, workers, ray_address, plots, on_start, on_result)
    return ablation


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
        raise BadInputError(
            f"--out {root}: {MANIFEST_FILE} is damaged; move it away to run into this folder"
        ) from None
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


def _run_locked(
    ablation: Ablation,
    runner: Runner,
    workers: int,
    ray_address: str | None,
    plots: bool,
    on_start: Callable[[int, int, int], None] | None,
    on_result: ProgressCallback | None,
) -> None:
    root = ablation.root
    pending: list[tuple[Episode, str]] = []
    ablation.kept = []
    for ep in ablation.episodes:
        entry = ablation.entries[ep.key]
        found = locate(ep, root)
        entry.kept = [*found.earlier, *(f"{name}: {why}" for name, why in found.kept)]
        ablation.kept += [(name, why) for name, why in found.kept]
        if found.summary is not None:
            entry.dir = found.dir_name
            entry.record(found.summary)
            continue
        set_aside(root, found.kept, ep.key, found.dir_name)
        entry.reset(found.dir_name)
        pending.append((ep, found.dir_name))
    ablation.write_manifest()
    if on_start is not None:
        done, successes, _ = ablation.counts()
        on_start(ablation.size, done, successes)

    def settle(ep: Episode, result: tuple[dict[str, Any] | None, str | None, bool]) -> None:
        summary, error, fatal = result
        entry = ablation.entries[ep.key]
        if summary is not None:
            entry.record(summary)
        else:
            entry.status, entry.error = "error", error
        ablation.write_manifest()
        if on_result is not None:
            on_result(entry, ablation)
        if fatal:
            raise BadInputError(f"episode {ep.key}: {error}")

    specs = [(ep, ep.spec(root, ablation.grid.scenario, plots=plots, dir_name=name)) for ep, name in pending]
    if ray_address is not None:
        from llmnav.ablate.ray_tasks import run_ray

        for ep, result in run_ray(runner, specs, ray_address):
            settle(ep, result)
    elif workers > 1 and len(specs) > 1:
        for ep, result in run_pool(runner, specs, workers):
            settle(ep, result)
    else:
        for ep, spec in specs:
            settle(ep, execute_episode(runner, spec))
