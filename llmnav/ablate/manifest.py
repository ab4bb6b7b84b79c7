"""The manifest of an ablation folder, and which of its episodes already hold a finished run."""

from __future__ import annotations

import json
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from llmnav.ablate.grid import Episode, GridSpec, expand
from llmnav.runlog import RUN_FILE, SUMMARY_FILE, write_json_atomic

MANIFEST_FILE = "manifest.json"
Status = Literal["pending", "done", "error"]


@dataclass
class ManifestEntry:
    """One episode's line in manifest.json."""

    key: str
    dir: str  # relative to the ablation folder
    task_id: str
    start_pose: int
    trial: int
    seed: int
    factors: dict[str, Any]
    status: Status = "pending"
    summary: str | None = None  # relative path of summary.json
    outcome: str | None = None
    success: bool | None = None
    score: float | None = None
    error: str | None = None

    def record(self, summary: dict[str, Any]) -> None:
        """Mark done with the episode's summary."""
        self.status, self.error = "done", None
        self.summary = f"{self.dir}/{SUMMARY_FILE}"
        self.outcome = summary.get("outcome")
        self.success = bool(summary.get("success"))
        self.score = summary.get("score")


@dataclass
class Ablation:
    """A grid expanded into episodes, bound to its folder."""

    grid: GridSpec
    root: Path
    episodes: list[Episode]
    entries: dict[str, ManifestEntry] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for ep in self.episodes:
            self.entries.setdefault(
                ep.key,
                ManifestEntry(
                    ep.key, ep.dir_name, ep.task_id, ep.start_pose, ep.trial, ep.seed, dict(ep.factors)
                ),
            )

    @property
    def size(self) -> int:
        """Number of episodes."""
        return len(self.episodes)

    def manifest(self) -> dict[str, Any]:
        """The manifest as data (no timestamps: an interrupted and resumed sweep gives the same one)."""
        entries = [self.entries[ep.key].__dict__ for ep in self.episodes]
        done = [e for e in entries if e["status"] == "done"]
        return {
            "name": self.grid.default_name(),
            "scenario": self.grid.scenario,
            "grid": self.grid.model_dump(mode="json"),
            "factors": list(self.grid.factors()),
            "size": self.size,
            "done": len(done),
            "successes": sum(1 for e in done if e["success"]),
            "episodes": entries,
        }

    def write_manifest(self) -> Path:
        """Rewrite manifest.json atomically."""
        path = self.root / MANIFEST_FILE
        write_json_atomic(path, self.manifest())
        return path


def plan(grid: GridSpec, root: Path) -> Ablation:
    """Expand the grid for the folder `root` (nothing is written)."""
    return Ablation(grid, Path(root), expand(grid))


def _finished(ep: Episode, run_dir: Path) -> dict[str, Any] | None:
    """The episode's summary when its folder holds a finished run of exactly this episode, else None."""
    summary_path = run_dir / SUMMARY_FILE
    try:
        summary = json.loads(summary_path.read_text(encoding="utf-8"))
        with open(run_dir / RUN_FILE, encoding="utf-8") as log:
            config = json.loads(log.readline())
    except (OSError, json.JSONDecodeError):
        return None
    if not isinstance(summary, dict) or not isinstance(config, dict) or "outcome" not in summary:
        return None
    reason = str(summary.get("reason") or "")
    if summary.get("cut_short") or reason.startswith(("crash", "interrupted")):
        return None
    task = config.get("task") or {}
    logged_backend = str(config.get("backend") or "")
    same = (
        str(task.get("id", "")).lower() == ep.task_id.lower()
        and config.get("start_pose_index") == ep.start_pose
        and config.get("options") == ep.options.model_dump(mode="json")
        # a backend spec may gain its default argument when logged ("local" -> "local:<model>")
        and (not logged_backend or logged_backend.split(":")[0] == ep.backend.split(":")[0])
    )
    return summary if same else None


def results_runs(ablation: Ablation) -> list[Any]:
    """The finished episodes as `llmnav.score.Run`s (for the closing tables)."""
    from llmnav.score import load_run

    runs = []
    for ep in ablation.episodes:
        if ablation.entries[ep.key].status == "done":
            runs.append(load_run(ablation.root / ep.dir_name))
    return runs


def table_keys(ablation: Ablation) -> list[str]:
    """Condition keys the closing tables group by: the factors with more than one value."""
    return [name for name, values in ablation.grid.factors().items() if len(values) > 1]


def describe_episodes(episodes: Iterable[Episode]) -> list[list[str]]:
    """Rows for `--dry-run`: key, task, pose, trial, seed, backend."""
    return [
        [ep.key, ep.task_id, str(ep.start_pose), str(ep.trial), str(ep.seed), ep.backend] for ep in episodes
    ]
