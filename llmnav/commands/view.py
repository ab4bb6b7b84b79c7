"""`llmnav view`: the HTML page of a run or a sweep, or the video of a run (argument parsing only)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from llmnav.commands.common import cli_errors, err_console


@cli_errors
def view(
    folder: Annotated[Path, typer.Argument(help="A run folder, or a sweep (ablation) folder of runs.")],
    out: Annotated[Path | None, typer.Option("--out", help="Page to write (default FOLDER/view.html).")] = None,
    open_page: Annotated[bool, typer.Option("--open", help="Open the page in the default browser.")] = False,
    force: Annotated[
        bool, typer.Option("--force", help="Replace an existing --out file that llmnav did not write.")
    ] = False,
    video: Annotated[
        Path | None, typer.Option("--video", help="Also render the run as a video: FILE.mp4 or FILE.gif.")
    ] = None,
    fps: Annotated[float, typer.Option("--fps", help="Video frames per second.")] = 10.0,
    seconds_per_step: Annotated[float, typer.Option("--seconds-per-step", help="Video seconds per decision.")] = 1.0,
) -> None:
    """Write one self-contained HTML page of a run (or of a sweep); optionally a video of the run."""
    from llmnav.view.api import write_view

    result = write_view(folder, out, force=force, video=video, fps=fps, seconds_per_step=seconds_per_step)
    err_console.print(f"page: {result.page}", highlight=False, soft_wrap=True)
    if result.video is not None:
        v = result.video
        err_console.print(
            f"video: {v.path} ({v.frames} frames at {v.fps:g} fps = {v.duration_s:.1f} s, {v.codec})",
            highlight=False,
            soft_wrap=True,
        )
    typer.echo(str(result.page))
    if open_page:
        import webbrowser

        webbrowser.open(result.page.resolve().as_uri())
