"""Figure of a waypoint plan: corridors, every attempt's waypoints, the valid plan and the target."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from llmnav.reporting.topview import TARGET_RGB, draw_scenario, draw_targets
from llmnav.scoring.metrics import SUCCESS_RADIUS_M

if TYPE_CHECKING:
    from llmnav.core.geometry import Pose2D
    from llmnav.planners.waypoints.planner import PlanResult
    from llmnav.world.scenario import Scenario

FIG_WIDTH_IN = 9.0  # [in] for a wide map; the height follows its aspect ratio
FIG_HEIGHT_IN = 11.0  # [in] for a tall map; the width follows


def plot_plan(scenario: Scenario, plan: PlanResult, start: Pose2D, out: Path) -> Path:
    """Rejected attempts in grey, the valid plan in blue, start green, target red.

    The dotted blue outlines are where waypoints may lie (each corridor shrunk by the rules' margin).
    """
    # deferred: matplotlib (about 0.3 s) loads only when a plan is drawn
    import matplotlib

    matplotlib.use("Agg")
    # deferred as above, and after the Agg backend is chosen (no display needed)
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle

    bx, by = scenario.bounds.x, scenario.bounds.y
    aspect = (by[1] - by[0]) / (bx[1] - bx[0])
    # fit the figure to the map, with room for the title, axis labels and the legend below
    if aspect <= 1.0:
        size = (FIG_WIDTH_IN, max(FIG_WIDTH_IN * aspect + 2.2, 4.0))
    else:
        size = (max((FIG_HEIGHT_IN - 2.2) / aspect + 1.5, 5.5), FIG_HEIGHT_IN)
    fig, ax = plt.subplots(figsize=size)
    draw_scenario(ax, scenario)
    margin = scenario.waypoint_rules.margin_m
    for index, corridor in enumerate(scenario.corridors):
        width = corridor.x[1] - corridor.x[0] - 2 * margin
        height = corridor.y[1] - corridor.y[0] - 2 * margin
        if width > 0 and height > 0:
            ax.add_patch(
                Rectangle(
                    (corridor.x[0] + margin, corridor.y[0] + margin),
                    width,
                    height,
                    fill=False,
                    edgecolor="tab:blue",
                    linestyle=":",
                    linewidth=1.0,
                    zorder=2,
                    label=f"waypoint area ({margin} m margin)" if index == 0 else None,
                )
            )
    for attempt in plan.attempts:
        if attempt.points and not attempt.valid:
            xs, ys = zip(*[(start.x, start.y), *attempt.points], strict=True)
            ax.plot(xs, ys, "x--", color="0.45", lw=0.9, zorder=5, label=f"attempt {attempt.number} (rejected)")
    if plan.waypoints:
        xs, ys = zip(*[(start.x, start.y), *plan.waypoints], strict=True)
        ax.plot(xs, ys, "o-", color="tab:blue", lw=2, zorder=6, label="valid plan")
        for index, (x, y) in enumerate(plan.waypoints, start=1):
            ax.annotate(str(index), (x, y), textcoords="offset points", xytext=(4, 4), fontsize=8, zorder=7)
    ax.plot(start.x, start.y, "o", color="tab:green", ms=9, zorder=7, label="start")

    draw_targets(ax, [plan.target], SUCCESS_RADIUS_M, legend=False)
    label = f"target {plan.target_id} (success within {SUCCESS_RADIUS_M:g} m)"
    ax.plot([], [], "*", color=TARGET_RGB, ms=11, label=label)
    ax.set_aspect("equal")
    ax.set_xlim(bx[0] - 0.3, bx[1] + 0.3)
    ax.set_ylim(by[0] - 0.3, by[1] + 0.3)
    tall = aspect > 1.0
    ax.legend(
        loc="upper center",
        bbox_to_anchor=(0.5, -0.06 if tall else -0.16),  # below the x label
        ncol=2 if tall else 3,
        fontsize=7,
        frameon=False,
    )
    valid = sum(a.valid for a in plan.attempts)
    ax.set_title(
        f"Waypoint plan to {plan.target_id} — {valid}/{len(plan.attempts)} valid "
        f"(WGSR {plan.wgsr:.0f} %), planning {plan.planning_time_s:.2f} s"
    )
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out
