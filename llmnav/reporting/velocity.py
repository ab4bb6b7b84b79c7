"""Velocity-profile figure of an FSM run: baseline, raw model suggestion and fused command over time."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from llmnav.runs.runlog import read_run

PROFILE_FILE = "velocity_profile.png"  # where the FSM planner leaves the figure in its run folder


def _pair(value: Any) -> bool:
    """[v, ω]: two numbers."""
    return (
        isinstance(value, list)
        and len(value) >= 2
        and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value[:2])
    )


def well_formed_cmd(record: dict[str, Any]) -> bool:
    """A `cmd` record the figure can draw (a hand-edited or damaged log may hold anything)."""
    raw = record.get("raw")
    return (
        _pair(record.get("base"))
        and _pair(record.get("fused"))
        and (raw is None or _pair(raw))
        and isinstance(record.get("t_sim", 0.0), (int, float))
    )


def plot_velocity_profile(run_dir: Path, out: Path) -> Path | None:
    """Draw linear and angular velocity from the run's `cmd` records; None when there are none."""
    records = [e for e in read_run(run_dir).of_type("planner") if e.get("kind") == "cmd" and well_formed_cmd(e)]
    if not records:
        return None
    # deferred: matplotlib (about 0.3 s) loads only when a figure is drawn
    import matplotlib

    matplotlib.use("Agg")
    # deferred with matplotlib: pyplot comes after the Agg backend is chosen
    import matplotlib.pyplot as plt

    t = [float(e.get("t_sim", 0.0)) for e in records]
    fig, axes = plt.subplots(2, 1, figsize=(9, 5.5), sharex=True)
    for axis, index, unit in ((axes[0], 0, "linear v [m/s]"), (axes[1], 1, "angular ω [rad/s]")):
        axis.plot(t, [e["base"][index] for e in records], label="baseline (FSM)", color="tab:blue")
        raw_t = [ti for ti, e in zip(t, records, strict=True) if e.get("raw") is not None]
        raw = [e["raw"][index] for e in records if e.get("raw") is not None]
        if raw:
            axis.plot(raw_t, raw, ".", ms=3, label="raw model suggestion", color="tab:orange")
        axis.plot(t, [e["fused"][index] for e in records], label="published (fused)", color="tab:green", lw=1.2)
        axis.set_ylabel(unit)
        axis.grid(alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8)
    axes[1].set_xlabel("simulation time [s]")
    fig.suptitle("FSM command profile")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out
