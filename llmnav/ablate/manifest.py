"""The manifest of an ablation folder, and which of its episodes already hold a finished run."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from llmnav.ablate.grid import MAX_EPISODES, Episode, GridSpec, expand
from llmnav.ablate.layout import Layout
from llmnav.errors import redact_userinfo
from llmnav.runs.runlog import SUMMARY_FILE, write_json_atomic

MANIFEST_FILE = "manifest.json"
Status = Literal["pending", "done", "error"]


# Navigation outcomes that are results. An episode aborted because no answer came (auth, connection,
# server error, replay divergence: the runner logs failure "backend") or by a crash says nothing about
# navigation: it is an error, and the next resume runs it again. Aborted by the model's own answers (no
# valid action after the corrections, every motion vetoed) is a result: rerunning it until it passes
# would bias the tables.
DONE_OUTCOMES = ("completed", "failed", "not_found")


def is_result(summary: dict[str, Any]) -> bool:
    """Whether a summary is a navigation result (else an error to run again)."""
    reason = str(summary.get("reason") or "")
    if summary.get("cut_short") or reason.startswith(("crash", "interrupted")):
        return False
    if summary.get("outcome") in DONE_OUTCOMES:
        return True
    metrics = summary.get("planner_metrics") or {}
    # a planner's own "aborted" (no valid action, every motion vetoed) carries no failure mark: a result
    return summary.get("outcome") == "aborted" and metrics.get("failure") != "backend"


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
    condition: str = ""  # hash of the episode's full condition (grid.condition), logged in its run
    status: Status = "pending"
    summary: str | None = None  # relative path of summary.json
    outcome: str | None = None
    success: bool | None = None
    score: float | None = None
    error: str | None = None
    kept: list[str] = field(default_factory=list)  # earlier folders of this episode, kept: "dir: why"
    cost_usd: float | None = None  # [USD] the run's model calls (None: unknown or not run)

    def reset(self, dir_name: str) -> None:
        """Pending, to be run into `dir_name`."""
        self.dir, self.status, self.error = dir_name, "pending", None
        self.summary = self.outcome = self.success = self.score = self.cost_usd = None

    def record(self, summary: dict[str, Any]) -> None:
        """Settle with the episode's summary: done, or an error when the run was aborted."""
        self.summary = f"{self.dir}/{SUMMARY_FILE}"
        self.outcome = summary.get("outcome")
        self.success = bool(summary.get("success"))
        self.score = summary.get("score")
        cost = summary.get("cost_usd", 0.0)  # summaries written before costs: runs of free backends then
        self.cost_usd = float(cost) if isinstance(cost, (int, float)) else None
        if is_result(summary):
            self.status, self.error = "done", None
        else:
            self.status = "error"
            self.error = f"{self.outcome or 'no outcome'}: {summary.get('reason') or 'no reason logged'}"


@dataclass
class Ablation:
    """A grid expanded into episodes, bound to its folder."""

    grid: GridSpec
    root: Path
    episodes: list[Episode]
    entries: dict[str, ManifestEntry] = field(default_factory=dict)
    kept: list[tuple[str, str]] = field(default_factory=list)  # folders set aside by the last run: (dir, why)
    layout: Layout | None = None  # how the last run placed its workers and model
    _grid_part: dict[str, Any] | None = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        for ep in self.episodes:
            self.entries.setdefault(
                ep.key,
                ManifestEntry(
                    ep.key,
                    ep.dir_name,
                    ep.task_id,
                    ep.start_pose,
                    ep.trial,
                    ep.seed,
                    dict(ep.factors),
                    ep.identity,
                ),
            )

    @property
    def size(self) -> int:
        """Number of episodes."""
        return len(self.episodes)

    def counts(self) -> tuple[int, int, int]:
        """(done, successes, errors) over the episodes."""
        entries = [self.entries[ep.key] for ep in self.episodes]
        done = [e for e in entries if e.status == "done"]
        return len(done), sum(1 for e in done if e.success), sum(1 for e in entries if e.status == "error")

    def _header(self) -> dict[str, Any]:
        """The manifest's grid part, worked out once per sweep.

        Naming the factors looks up every registered planner (an entry-point scan of all installed
        packages, about 50 ms); done per episode it cost a sweep's parent a tenth of a core.
        """
        if self._grid_part is None:
            self._grid_part = without_credentials(
                {
                    "name": self.grid.default_name(),
                    "scenario": self.grid.scenario,
                    "grid": self.grid.model_dump(mode="json"),
                    "factors": list(self.grid.factors()),
                }
            )
        return self._grid_part

    def manifest(self) -> dict[str, Any]:
        """The manifest as data (no timestamps: an interrupted and resumed sweep gives the same one)."""
        entries = [dict(self.entries[ep.key].__dict__) for ep in self.episodes]
        done, successes, errors = self.counts()
        return {
            **self._header(),
            "size": self.size,
            "done": done,
            "errors": errors,
            "successes": successes,
            **({"layout": self.layout.record()} if self.layout is not None else {}),
            "episodes": entries,
        }

    def write_manifest(self) -> Path:
        """Rewrite manifest.json atomically (credentials in a backend URL are not written)."""
        path = self.root / MANIFEST_FILE
        write_json_atomic(path, without_credentials(self.manifest()))
        return path


def without_credentials(data: Any) -> Any:
    """`data` with every URL's `user:password@` replaced by `***@` (a manifest is shared with the results)."""
    if isinstance(data, str):
        return redact_userinfo(data)
    if isinstance(data, dict):
        return {k: without_credentials(v) for k, v in data.items()}
    if isinstance(data, list):
        return [without_credentials(v) for v in data]
    return data


def plan(grid: GridSpec, root: Path, max_episodes: int = MAX_EPISODES) -> Ablation:
    """Expand the grid for the folder `root` (nothing is written); refused above `max_episodes`."""
    return Ablation(grid, Path(root), expand(grid, max_episodes))


def results_runs(ablation: Ablation) -> list[Any]:
    """The finished episodes as `llmnav.runs.folders.Run`s (for the closing tables)."""
    from llmnav.runs.folders import load_run

    runs = []
    for ep in ablation.episodes:
        if ablation.entries[ep.key].status == "done":
            runs.append(load_run(ablation.root / ablation.entries[ep.key].dir))
    return runs


def table_keys(ablation: Ablation) -> list[str]:
    """Condition keys the closing tables group by: the factors with more than one value."""
    return [name for name, values in ablation.grid.factors().items() if len(values) > 1]


def describe_episodes(episodes: Iterable[Episode]) -> list[list[str]]:
    """Rows for `--dry-run`: key, task, pose, trial, seed, backend."""
    return [[ep.key, ep.task_id, str(ep.start_pose), str(ep.trial), str(ep.seed), ep.backend] for ep in episodes]
