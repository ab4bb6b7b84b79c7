"""Ablation sweeps: a grid of conditions → episodes, run resumably and in parallel, with a manifest.

A grid is the cartesian product of the ablated factors (`planner`, `backend`, `wording`, and any planner
option such as `lidar_sectors` or `prompt`) over tasks × start poses × trials. Each episode has a key naming it
(`T8-p1-t2-lidar_sectors=3`: task, start pose, trial and the factors with several values), one run
folder under the ablation folder named from that key, and a seed derived from (base seed, task, pose,
trial): every condition sees the same seeds, so differences between conditions come from the factor, not
from the noise, and results never depend on the order or the process that ran an episode.

`manifest.json` (rewritten atomically after every episode) lists every episode with its key, folder,
seed, factors, condition hash, status and summary, and the layout the last run took (`layout`). An
ablation folder holds one grid (another grid is refused) and one sweep at a time (a lock). Running the
same grid again keeps every episode whose folder holds a finished run of exactly its condition
(`grid.condition`: scenario file, task, pose, trial, backend spec, every option, prompt templates) and
runs the others into new folders; nothing is ever deleted (`resume`). An episode aborted by a backend
failure is an error and runs again on the next resume.
Episodes run through `llmnav.runs.runner.run_episode` — in this process, in a spawn process pool whose
workers die with the parent, or as Ray tasks (`executors`); the parent alone writes the manifest. With
the local model, the pool's workers each load a copy or share one model server (`layout`).
"""

from llmnav.ablate.executors import Runner, execute_episode, worker_model_threads
from llmnav.ablate.grid import (
    CORE_FACTORS,
    DEFAULT_BACKEND,
    MAX_EPISODES,
    Episode,
    GridSpec,
    episode_key,
    episode_seed,
    expand,
    grid_from_mapping,
    load_grid_file,
    parse_poses,
    split_list,
)
from llmnav.ablate.layout import LAYOUTS, Layout, choose
from llmnav.ablate.manifest import (
    MANIFEST_FILE,
    Ablation,
    ManifestEntry,
    describe_episodes,
    plan,
    results_runs,
    table_keys,
)
from llmnav.ablate.sweep import ProgressCallback, run

__all__ = [
    "LAYOUTS",
    "Layout",
    "choose",
    "MAX_EPISODES",
    "DEFAULT_BACKEND",
    "CORE_FACTORS",
    "MANIFEST_FILE",
    "Ablation",
    "Episode",
    "GridSpec",
    "ManifestEntry",
    "ProgressCallback",
    "Runner",
    "describe_episodes",
    "episode_key",
    "episode_seed",
    "execute_episode",
    "expand",
    "grid_from_mapping",
    "load_grid_file",
    "parse_poses",
    "plan",
    "results_runs",
    "run",
    "split_list",
    "table_keys",
    "worker_model_threads",
]
