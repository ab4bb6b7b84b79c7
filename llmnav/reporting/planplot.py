"""Figure of a waypoint plan: corridors, every attempt's waypoints, the valid plan and the target."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from llmnav.geometry import Pose2D
    from llmnav.planners.waypoints import PlanResult
    from llmnav.scenario import Scenario


def plot_plan(scenario: Scenario, plan: PlanResult, start: Pose2D, out: Path) -> Path:
    """Rejected attempts in grey, the valid plan in blue, start green, target red."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from llmnav.reporting.topview import draw_scenario

    fig, ax = plt.subplots(figsize=(9, 6))
    draw_scenario(ax, scenario)
    for attempt in plan.attempts:
        if attempt.points and not attempt.valid:
            xs, ys = zip(*[(start.x, start.y), *attempt.points], strict=True)
            ax.plot(xs, ys, "x--", color="0.55", lw=0.8, label=f"attempt {attempt.number} (rejected)")
    if plan.waypoints:
        xs, ys = zip(*[(start.x, start.y), *plan.waypoints], strict=True)
        ax.plot(xs, ys, "o-", color="tab:blue", lw=2, label="valid plan")
        for index, (x, y) in enumerate(plan.waypoints, start=1):
            ax.annotate(str(index), (x, y), textcoords="offset points", xytext=(4, 4), fontsize=8)
    ax.plot(start.x, start.y, "o", color="tab:green", ms=9, label="start")
    ax.plot(*plan.target, "*", color="tab:red", ms=14, label=f"target {plan.target_id}")
    ax.set_aspect("equal")
    ax.legend(loc="best", fontsize=7)
    ax.set_title(f"Waypoint plan — WGSR {plan.wgsr:.0f} %, {plan.planning_time_s:.2f} s")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out
