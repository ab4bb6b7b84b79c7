"""The one entry point the commands call: a page (and optionally a video) for a run or sweep folder."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from llmnav.ablate import MANIFEST_FILE
from llmnav.errors import BadInputError
from llmnav.runs.runlog import RUN_FILE
from llmnav.view.model import build_run_view
from llmnav.view.page import PAGE_FILE, check_out, check_target, run_page, sweep_page, write_page
from llmnav.view.video import VideoInfo, check_timing, render_video


@dataclass
class ViewResult:
    """What `write_view` wrote."""

    page: Path
    kind: str  # "run" | "sweep"
    video: VideoInfo | None = None


def folder_kind(folder: Path) -> str:
    """`run` (holds run.jsonl), `sweep` (a manifest or run folders below it); BadInputError otherwise."""
    if not folder.exists():
        raise BadInputError(f"{folder}: no such folder")
    if not folder.is_dir():
        raise BadInputError(f"{folder}: not a folder (give a run folder or a sweep folder)")
    if (folder / RUN_FILE).exists():
        return "run"
    if (folder / MANIFEST_FILE).exists() or next(folder.rglob(RUN_FILE), None) is not None:
        return "sweep"
    raise BadInputError(f"{folder}: not a run folder (no {RUN_FILE}) nor a sweep folder (no runs below it)")


def write_view(
    folder: Path,
    out: Path | None = None,
    *,
    force: bool = False,
    video: Path | None = None,
    fps: float = 10.0,
    seconds_per_step: float = 1.0,
) -> ViewResult:
    """Write the page of `folder` (default `folder/view.html`) and, for a run, its video when asked."""
    folder = Path(folder)
    kind = folder_kind(folder)
    page = Path(out) if out is not None else folder / PAGE_FILE
    check_out(page, force=force)
    if video is not None:
        if kind != "run":
            raise BadInputError("--video needs a run folder, not a sweep")
        if video.suffix.lower() not in (".mp4", ".gif"):
            raise BadInputError(f"--video {video}: give a file ending in .mp4 or .gif")

        check_timing(fps, seconds_per_step)  # bad flags fail before the page is written
        # a video carries no mark of its writer: an existing file is replaced only when forced
        check_target(video, "--video", force=force, ours=lambda _: False)
        if video.absolute() == page.absolute():
            raise BadInputError(f"--video {video}: is the page's --out too; choose another file")
    if kind == "run":
        write_page(run_page(folder), page)
    else:
        write_page(sweep_page(folder, page), page)
    info = None
    if video is not None:
        info = render_video(build_run_view(folder), video, fps=fps, seconds_per_step=seconds_per_step)
    return ViewResult(page, kind, info)
