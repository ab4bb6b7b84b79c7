"""Bar charts of score and success by condition, with error bars (matplotlib, Agg backend)."""

from __future__ import annotations

import math
import textwrap
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from llmnav.errors import BadInputError
from llmnav.scoring.stats import describe, wilson_interval

if TYPE_CHECKING:
    from llmnav.runs.folders import Run


def _safe(name: str) -> str:
    return "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in name).strip("_") or "all"


def plot_conditions(runs: Sequence[Run], keys: Sequence[str], out_dir: Path) -> list[Path]:
    """Per task: mean score ± SD and success rate with Wilson's 95 % interval per condition; returns the PNGs."""
    # deferred: matplotlib (about 0.3 s) loads only when a chart is drawn
    import matplotlib

    matplotlib.use("Agg")
    # deferred with matplotlib: pyplot after the Agg backend is chosen; scoring brings pydantic and yaml
    import matplotlib.pyplot as plt

    from llmnav.scoring.score import group_runs

    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise BadInputError(f"--plot {out_dir}: cannot create folder: {err.strerror or err}") from None
    by_task: dict[str, list[tuple[str, list[Run]]]] = {}
    for task, cond, group in group_runs(runs, keys):
        by_task.setdefault(task, []).append((cond, group))
    written = []
    for task, groups in by_task.items():
        fig = condition_figure(task, groups, keys)
        try:
            path = out_dir / f"{_safe(task)}.png"
            fig.savefig(path, dpi=110)
        finally:
            plt.close(fig)
        written.append(path)
    return written


LABEL_CHARS = 16  # a tick label's line length: about what fits under a bar 1.6 inches wide at 8 pt


def condition_figure(task: str, groups: Sequence[tuple[str, Sequence[Run]]], keys: Sequence[str]) -> Any:
    """One task's figure: a bar per condition, its label wrapped to the bar's width (never tilted into the next)."""
    # deferred: matplotlib (about 0.3 s) loads only when a chart is drawn
    import matplotlib.pyplot as plt

    labels = [cond for cond, _ in groups]
    score_mean, score_sd, rate, rate_err = [], [], [], []
    for _, group in groups:
        scores = [float(r.summary["score"]) for r in group if isinstance(r.summary.get("score"), (int, float))]
        d = describe(scores)
        score_mean.append(d.mean if d.n else math.nan)
        score_sd.append(d.sd if d.n > 1 else 0.0)
        ok = sum(1 for r in group if r.summary.get("success"))
        p = ok / len(group)
        low, high = wilson_interval(ok, len(group))
        rate.append(p)
        rate_err.append((p - low, high - p))
    wrapped = ["\n".join(textwrap.wrap(label, LABEL_CHARS, break_on_hyphens=False) or [label]) for label in labels]
    lines = max(w.count("\n") + 1 for w in wrapped)
    # The figure grows with the number of conditions and with the lines of the longest label.
    fig, axes = plt.subplots(
        1, 2, figsize=(max(6.0, 2 * (1.6 * len(labels) + 0.8)), 3.0 + 0.16 * lines), constrained_layout=True
    )
    positions = list(range(len(labels)))
    axes[0].bar(positions, score_mean, yerr=score_sd, capsize=4, color="#4c72b0")
    axes[0].set_ylabel("score S (mean ± SD)")
    axes[1].bar(positions, rate, yerr=list(zip(*rate_err, strict=True)), capsize=4, color="#55a868")
    axes[1].set_ylabel("success rate (95 % Wilson)")
    for ax in axes:
        ax.set_ylim(0, 1.05)
        ax.set_xticks(positions, wrapped, fontsize=8)
    fig.suptitle(f"{task} by {', '.join(keys)}" if keys else task)
    return fig
