"""Where a sweep's model runs: a copy in every worker, or one shared copy with a slot per worker.

With the local backend and several workers, each worker loads its own copy of the model ("per-worker").
The other layout ("shared") loads the model once, in one server process with a slot per worker
(`llmnav.serve.shared`, on 127.0.0.1 only), and the workers' `local` backends send it the same requests
they would have answered themselves (`llmnav.backends.served`). `choose` takes the layout measured
faster (`MEASURED`) unless told which; a sweep with no local model, one worker or Ray has nothing to
share. The sweep says which layout it took and records it in the manifest.

Answers do not depend on the layout: at temperature 0 with constrained decoding the shared server gave
the same answers and scores as the in-process model (whole episodes compared, timing fields aside:
`python -m bench ablate`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Literal

from llmnav.backends.base import parse_spec
from llmnav.backends.local import HF_PREFIX, model_threads
from llmnav.errors import ModelUnavailableError
from llmnav.serve import gguf_path

LayoutName = Literal["auto", "shared", "per-worker"]
LAYOUTS: tuple[str, ...] = ("auto", "shared", "per-worker")

# Episodes per minute of a model-bound sweep with 2 workers on this 2-core machine, by layout: hybrid
# planner, embedded SmolLM2-135M, factory T1 and T5 from poses 1-2, at most 6 decisions (`python -m bench
# ablate` measures it again), with both cores free (load average 1.4). Each per-worker copy runs 1 thread;
# the shared server runs 1 thread beside the workers' simulations (with 2 threads it was 10x slower under
# load: its threads wait for each other at every layer, and one of them always waits for a core). Under
# load (average 2.3-6) the two layouts were level: shared/per-worker wall time 0.98 in two interleaved
# A/B series of 3-4 sweeps each. So a copy per worker stays the default; the shared layout saves the
# memory of all copies but one.
MEASURED: dict[str, float] = {"per-worker": 21.83, "shared": 17.07}  # [episodes/min]


@dataclass(frozen=True)
class Layout:
    """How a sweep runs its episodes and its model (as recorded in the manifest)."""

    workers: int
    model: str  # "none" (no local model), "in-process", "per-worker", "shared", "ray", "runner's own"
    model_path: str | None = None
    slots: int = 0  # the shared server's
    threads: int = 0  # the shared server's
    chosen: str = "auto"  # "auto" or the layout asked for

    @property
    def shared(self) -> bool:
        """Whether one server process holds the model for every worker."""
        return self.model == "shared"

    def record(self) -> dict[str, Any]:
        """The manifest's `layout` entry."""
        return asdict(self)

    def describe(self) -> str:
        """One line for the user."""
        how = "picked" if self.chosen == "auto" else "as asked"
        if self.model == "shared":
            name = Path(self.model_path or "").name
            return (
                f"model layout: shared ({how}) — one loaded {name} with {self.slots} slots and {self.threads} "
                f"thread(s) on 127.0.0.1 for {self.workers} workers, instead of a copy in each"
            )
        if self.model == "per-worker":
            why = ", measured faster than one shared copy" if self.chosen == "auto" else ""
            return f"model layout: per-worker ({how}) — each of the {self.workers} workers loads its own copy{why}"
        return f"model layout: {self.model} ({self.workers} worker(s))"


def local_models(backends: list[str]) -> set[str]:
    """The GGUF files that the `local` backends among `backends` load (transformers models excluded)."""
    paths = set()
    for spec in backends:
        name, arg = parse_spec(spec)
        if name == "local" and not (arg or "").startswith(HF_PREFIX):
            try:
                paths.add(str(gguf_path(arg)))
            except ModelUnavailableError:  # each episode reports it; nothing to share
                continue
    return paths


def faster() -> str:
    """The layout measured faster (per-worker on a tie: nothing to start)."""
    return "shared" if MEASURED["shared"] > MEASURED["per-worker"] else "per-worker"


def choose(
    backends: list[str], workers: int, *, requested: str = "auto", ray: bool = False, runs_backends: bool = True
) -> Layout:
    """The layout for a sweep of episodes with these backend specs on `workers` workers.

    `runs_backends`: whether the episode runner builds the backends the specs name (a custom runner
    with a backend of its own has no model to share unless the layout is asked for).
    """
    if ray:
        return Layout(workers, "ray", chosen=requested)
    if not runs_backends and requested == "auto":
        return Layout(workers, "runner's own", chosen=requested)
    models = local_models(backends)
    if not models:
        return Layout(workers, "none", chosen=requested)
    if workers <= 1:
        return Layout(workers, "in-process", sorted(models)[0], chosen=requested)
    pick = faster() if requested == "auto" else requested
    if pick != "shared" or len(models) > 1:  # several models: each worker keeps its own copies
        return Layout(workers, "per-worker", ",".join(sorted(models)), chosen=requested)
    # The server answers while the workers simulate: it keeps a core free for them (or $LLMNAV_LOCAL_THREADS).
    threads = model_threads(beside_simulation=True)
    return Layout(workers, "shared", next(iter(models)), slots=workers, threads=threads, chosen=requested)
