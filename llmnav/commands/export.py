"""`llmnav export`: a run folder in another format (MCAP of ROS 2 messages) — argument parsing only."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from llmnav.commands.common import check_output_path, cli_errors, err_console, esc
from llmnav.errors import BadInputError

if TYPE_CHECKING:
    from llmnav.ros.export import ExportResult


@cli_errors
def export(
    run: Annotated[Path, typer.Argument(help="A run folder (run.jsonl and images/), or a sweep folder of runs.")],
    mcap: Annotated[
        Path | None,
        typer.Option(
            "--mcap",
            help="MCAP file of ROS 2 messages to write (Foxglove, ros2 bag, rosbags); for a sweep, a folder of them.",
        ),
    ] = None,
    ros_only: Annotated[
        bool,
        typer.Option(
            "--ros-only", help="Decisions as std_msgs/String JSON instead of JSON messages (for rosbags, ros2 bag)."
        ),
    ] = False,
) -> None:
    """Write a run as ROS 2 data: /odom, /tf, /scan, /map, camera images, /cmd_vel, /plan and the decisions."""
    if mcap is None:
        raise BadInputError("say what to write: --mcap OUT.mcap")
    # deferred: the MCAP export brings numpy (about 0.1 s), not for `llmnav --help`
    from llmnav.ros.export import export_mcap, export_sweep, sweep_runs
    from llmnav.runs.runlog import RUN_FILE

    if not (run / RUN_FILE).exists() and run.is_dir():  # a sweep: one file per run into the folder --mcap
        if not sweep_runs(run):
            raise BadInputError(f"{run}: neither a run folder nor a folder of runs")
        if mcap.suffix:
            raise BadInputError(f"--mcap {mcap}: {run} is a sweep; give a folder for its runs' MCAP files")
        check_output_path(mcap / "x.mcap", "--mcap", [run])
        results = export_sweep(run, mcap, ros_only=ros_only)
        err_console.print(f"wrote {len(results)} MCAP file(s) into {esc(str(mcap))}", highlight=False, soft_wrap=True)
        return
    if mcap.suffix.lower() != ".mcap":
        raise BadInputError(f"--mcap {mcap}: give a file name ending in .mcap")
    check_output_path(mcap, "--mcap", [run])
    report(export_mcap(run, mcap, ros_only=ros_only))


def report(result: ExportResult) -> None:
    """What one export wrote, and what the run lacked, on stderr."""
    topics = ", ".join(f"{topic} {n}" for topic, n in sorted(result.counts.items()))
    err_console.print(f"wrote {esc(str(result.path))}: {esc(topics)}", highlight=False, soft_wrap=True)
    if result.lacks:
        err_console.print(f"note: the run lacks {esc('; '.join(result.lacks))}", highlight=False, soft_wrap=True)
    if result.skipped:
        err_console.print(f"note: {result.skipped} damaged event(s) skipped", highlight=False, soft_wrap=True)
