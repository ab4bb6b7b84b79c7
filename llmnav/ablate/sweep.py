"""Running an ablation: settle which episodes are finished, run the others, rewrite the manifest after each."""

from __future__ import annotations

import shutil
from collections.abc import Callable
from typing import Any

from llmnav.ablate.executors import Runner, _default_runner, _run_pool, _run_ray, execute_episode
from llmnav.ablate.grid import Episode
from llmnav.ablate.manifest import Ablation, ManifestEntry, _finished
from llmnav.errors import BadInputError

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
    runner = runner or _default_runner()
    root = ablation.root
    try:
        root.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise BadInputError(f"--out {root}: cannot create folder: {err.strerror or err}") from None
    pending: list[Episode] = []
    for ep in ablation.episodes:
        entry = ablation.entries[ep.key]
        summary = _finished(ep, root / ep.dir_name)
        if summary is not None:
            entry.record(summary)
            continue
        entry.status, entry.summary, entry.outcome, entry.success, entry.score = (
            "pending",
            None,
            None,
            None,
            None,
        )
        if (root / ep.dir_name).exists():  # cut short or inconsistent: start it afresh
            shutil.rmtree(root / ep.dir_name)
        pending.append(ep)
    ablation.write_manifest()
    if on_start is not None:
        done = [e for e in ablation.entries.values() if e.status == "done"]
        on_start(ablation.size, len(done), sum(1 for e in done if e.success))

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

    specs = [(ep, ep.spec(root, ablation.grid.scenario, plots=plots)) for ep in pending]
    if ray_address is not None:
        for ep, result in _run_ray(runner, specs, ray_address):
            settle(ep, result)
    elif workers > 1 and len(specs) > 1:
        for ep, result in _run_pool(runner, specs, workers):
            settle(ep, result)
    else:
        for ep, spec in specs:
            settle(ep, execute_episode(runner, spec))
    return ablation
