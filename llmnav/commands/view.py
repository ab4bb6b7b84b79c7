"""`llmnav view`: the HTML page of a run or a sweep, or the video of a run (argument parsing only)."""

from __future__ import annotations

import webbrowser
from pathlib import Path
from typing import Annotated

import typer

from llmnav.commands.common import cli_errors, err_console
from llmnav.errors import BadInputError
from llmnav.view.shot import screenshot as take


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
    screenshot: Annotated[
        Path | None, typer.Option("--screenshot", help="Also save a PNG of the page as headless Chromium shows it.")
    ] = None,
    step: Annotated[
        int | None, typer.Option("--step", min=1, help="Decision (1-based) the page opens at and the screenshot shows.")
    ] = None,
    size: Annotated[str, typer.Option("--size", help="Screenshot window size WIDTHxHEIGHT in pixels.")] = "1280x800",
) -> None:
    """Write one self-contained HTML page of a run (or of a sweep); optionally a video of the run."""
    # deferred: the page writer brings pydantic and yaml (about 0.15 s), not for `llmnav --help`
    from llmnav.view.api import write_view

    width, height = _size(size)  # bad flags fail before anything is written
    if screenshot is not None and screenshot.suffix.lower() != ".png":
        raise BadInputError(f"--screenshot {screenshot}: give a file ending in .png")
    result = write_view(folder, out, force=force, video=video, fps=fps, seconds_per_step=seconds_per_step)
    if result.video is not None:
        v = result.video
        err_console.print(
            f"video: {v.path} ({v.frames} frames at {v.fps:g} fps = {v.duration_s:.1f} s, {v.codec})",
            highlight=False,
            soft_wrap=True,
        )
    if screenshot is not None:
        err_console.print(f"screenshot: {take(result.page, screenshot, step=step, width=width, height=height)}")
    typer.echo(str(result.page))
    if open_page:
        webbrowser.open(result.page.resolve().as_uri() + (f"#step={step}" if step is not None else ""))


def _size(text: str) -> tuple[int, int]:
    """`1280x800` → (1280, 800)."""
    width, sep, height = text.lower().partition("x")
    if not (sep and width.isdigit() and height.isdigit() and 100 <= int(width) <= 4000 and 100 <= int(height) <= 4000):
        raise BadInputError(f"--size {text!r}: expected WIDTHxHEIGHT in pixels, e.g. 1280x800")
    return int(width), int(height)
