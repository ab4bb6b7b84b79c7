"""`llmnav export`: a run folder in another format (MCAP of ROS 2 messages) — argument parsing only."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from llmnav.commands.common import check_output_path, cli_errors, err_console, esc
from llmnav.errors import BadInputError


@cli_errors
def export(
    run: Annotated[Path, typer.Argument(help="A run folder (run.jsonl and images/).")],
    mcap: Annotated[
        Path | None, typer.Option("--mcap", help="Write an MCAP file of ROS 2 messages (Foxglove, ros2 bag, rosbags).")
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
    if mcap.suffix.lower() != ".mcap":
        raise BadInputError(f"--mcap {mcap}: give a file name ending in .mcap")
    check_output_path(mcap, "--mcap", [run])
    from llmnav.ros.export import export_mcap

    result = export_mcap(run, mcap, ros_only=ros_only)
    topics = ", ".join(f"{topic} {n}" for topic, n in sorted(result.counts.items()))
    err_console.print(f"wrote {esc(str(result.path))}: {esc(topics)}", highlight=False, soft_wrap=True)
    if result.lacks:
        err_console.print(f"note: the run lacks {esc('; '.join(result.lacks))}", highlight=False, soft_wrap=True)
    if result.skipped:
        err_console.print(f"note: {result.skipped} damaged event(s) skipped", highlight=False, soft_wrap=True)
