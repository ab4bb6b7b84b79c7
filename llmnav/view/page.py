"""Self-contained HTML pages of a run or a sweep, rendered from Jinja2 templates.

A page is one file: the CSS, the plain JavaScript and the camera images (as recorded, base64 data URIs)
are inside it, so it opens from disk with no server and no network. Every value from a run goes
through Jinja's autoescaping (model text is hostile), and the only JSON in the page goes through its
`tojson` filter, which escapes `<`, `>` and `&`.

`run_page` / `sweep_page` return the HTML; `write_page` writes it atomically and refuses to overwrite a
file it did not write itself unless forced (every page carries a generator tag to tell).
"""

from __future__ import annotations

import base64
import math
import os
import tempfile
from collections.abc import Callable
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING, Any
from urllib.parse import quote

from llmnav.core.safefiles import (
    IMAGE_LIMIT,
    PAGE_GENERATOR,
    SUMMARY_LIMIT,
    UnsafeFileError,
    image_kind,
    is_our_page,
    read_bytes,
    write_text,
)
from llmnav.core.safefiles import loads as bounded_loads
from llmnav.errors import BadInputError
from llmnav.reporting.velocity import PROFILE_FILE, plot_velocity_profile
from llmnav.runs.locking import LOCK_FILE
from llmnav.runs.runlog import IMAGES_DIR, RUN_FILE, SUMMARY_FILE, SUPERSEDED_FILE
from llmnav.scoring.stats import clip_interval, describe, wilson_interval
from llmnav.sensing.relevance import CONTENT_FREE_TASK
from llmnav.view.basemap import draw_base_map, page_size
from llmnav.view.drawing import arrow, lidar_wedges, points_attr, svg_point
from llmnav.view.model import as_dict, as_pose, build_run_view

GENERATOR = PAGE_GENERATOR  # the page's <meta name="generator">: how `write_page` knows its own files

if TYPE_CHECKING:
    from jinja2 import Environment

    from llmnav.runs.folders import Run
    from llmnav.scoring.score import Table
    from llmnav.view.model import RunView, StepView

PAGE_FILE = "view.html"  # default page name inside a run or sweep folder
ARROW_M = 0.5  # [m] heading arrows on the map


@lru_cache(maxsize=1)
def environment() -> Environment:
    """The Jinja2 environment: templates of this package, autoescaping on.

    Undefined values render empty: a field an older or partial log lacks must not break the page.
    """
    # deferred: jinja2 (about 0.04 s) loads only when a page is rendered
    from jinja2 import Environment, PackageLoader, select_autoescape

    env = Environment(
        loader=PackageLoader("llmnav.view", "templates"),
        autoescape=select_autoescape(("html", "j2", "svg"), default=True),
        trim_blocks=True,
        lstrip_blocks=True,
    )
    env.filters["num"] = _num
    env.filters["pose"] = _pose
    env.filters["joined"] = _joined

    env.globals["content_free_task"] = CONTENT_FREE_TASK
    return env


def _num(value: Any, digits: int = 2, unit: str = "") -> str:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return "—" if value is None else str(value)
    text = f"{value:.{digits}f}" if isinstance(value, float) else str(value)
    return f"{text} {unit}".rstrip()


def _pose(pose: Any) -> str:
    if not isinstance(pose, (list, tuple)) or len(pose) < 2:
        return "—"
    try:
        x, y = float(pose[0]), float(pose[1])
        yaw = f", heading {math.degrees(float(pose[2])):.0f}°" if len(pose) > 2 else ""
    except (TypeError, ValueError):
        return str(pose)
    return f"x {x:.2f} m, y {y:.2f} m{yaw}"


def _joined(value: Any, separator: str = ", ") -> str:
    """A logged list as text; anything else (a hand-edited log) as it is."""
    if isinstance(value, (list, tuple)):
        return separator.join(str(item) for item in value)
    return "" if value is None else str(value)


def data_uri(path: Path, root: Path) -> str | None:
    """A camera image in `root` as a data URI (its bytes as recorded); None when it cannot be embedded.

    Only a regular file inside the run folder, of at most IMAGE_LIMIT bytes, that starts as a JPEG or
    PNG does: a page is meant for sharing, and `images/x.jpg → ~/.ssh/id_rsa` must not end up in it.
    """
    try:
        data = read_bytes(path, limit=IMAGE_LIMIT, root=root)
    except (OSError, UnsafeFileError):
        return None
    kind = image_kind(data)
    return None if kind is None else f"data:image/{kind};base64," + base64.b64encode(data).decode("ascii")


# --- the run page --------------------------------------------------------------------------------


def _marker(step: StepView) -> dict[str, Any] | None:
    pose = step.pose_before or step.pose_after
    if not isinstance(pose, list) or len(pose) < 2:
        return None
    x, y = svg_point(float(pose[0]), float(pose[1]))
    return {"index": step.index, "cx": x, "cy": y, "label": step.label}


def _overlay(step: StepView) -> dict[str, Any]:
    """What the map shows for the selected decision: poses, waypoint attempts, replans."""

    def heading(pose: list[float] | None) -> dict[str, float] | None:
        return arrow(pose, ARROW_M) if pose is not None and len(pose) >= 3 else None

    attempts = []
    for a in step.attempts:
        raw = a.get("points")
        points = [p for p in (as_pose(q) for q in (raw if isinstance(raw, list) else [])) if p is not None]
        if points:
            start = step.pose_before or points[0]
            attempts.append(
                {"points": points_attr([start, *points]), "valid": bool(a.get("valid")), "number": a.get("attempt")}
            )
    replans = []
    for r in step.replans:
        obstacle = as_pose(r.get("obstacle"))
        replans.append(
            {
                "pose": heading(as_pose(r.get("pose"))),
                "obstacle": None if obstacle is None else svg_point(obstacle[0], obstacle[1]),
                "reason": r.get("reason"),
            }
        )
    return {
        "index": step.index,
        "before": heading(step.pose_before),
        "after": heading(step.pose_after),
        "attempts": attempts,
        "replans": replans,
        "frontiers": _frontier_marks(step),
    }


def _frontier_marks(step: StepView) -> list[dict[str, Any]]:
    """The decision's frontiers on the map: a dot each, sized by value (or utility), the chosen one marked.

    The label is the value where the decision scored its frontiers (log utility + PMI), else the utility.
    """
    chosen = step.chosen
    marks = []
    for row in step.frontiers:
        at = as_pose(row.get("at"))
        if at is None:
            continue
        x, y = svg_point(at[0], at[1])
        value, utility = row.get("value"), row.get("utility")
        scored = isinstance(value, (int, float)) and not isinstance(value, bool)
        shown = value if scored else utility
        number = float(shown) if isinstance(shown, (int, float)) else 0.0
        near = ", ".join(str(n) for n in row.get("near") or []) or "nothing known near"
        words = row.get("description") or near
        title = f"frontier {row.get('option')}: {words}; " + (
            f"value {number:+.1f} (PMI {row.get('pmi')}, utility {utility})" if scored else f"utility {number:.2f}"
        )
        label = f"{number:+.1f}" if scored else f"{number:.1f}"
        marks.append({"cx": x, "cy": y, "label": label, "title": title, "chosen": row.get("option") == chosen})
    return marks


STRIP_W, STRIP_PAD = 760, 36  # [px] suggestion-outcome strip: width and left margin


def _velocity_profile(view: RunView) -> str | None:
    """The velocity-profile figure (`llmnav.reporting.velocity`) as a PNG data URI.

    The planner draws it at the end of a run; a run cut short gets it drawn now.
    """
    path: Path | None = view.run_dir / PROFILE_FILE
    with tempfile.TemporaryDirectory(prefix="llmnav-view-") as tmp:
        if path is None or not path.is_file():
            path = plot_velocity_profile(view.run_dir, Path(tmp) / PROFILE_FILE)
        if path is None:
            return None
        return data_uri(path, path.parent)


def _velocity_charts(view: RunView) -> dict[str, Any] | None:
    """The velocity profile and a strip of suggestion outcomes over simulation time."""
    profile = view.profile
    if profile is None:
        return None
    verdicts: dict[str, int] = {}
    for s in profile.suggestions:
        verdicts[str(s.get("verdict"))] = verdicts.get(str(s.get("verdict")), 0) + 1

    def received(s: dict[str, Any]) -> float:
        value = s.get("t_recv")
        return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else 0.0

    t1 = max([*profile.t, *(received(s) for s in profile.suggestions), 1.0])
    span = STRIP_W - STRIP_PAD - 8
    marks = [
        {
            "x": round(STRIP_PAD + received(s) / t1 * span, 2),
            "verdict": str(s.get("verdict")),
            "detail": s.get("detail"),
            "t": s.get("t_recv"),
        }
        for s in profile.suggestions
    ]
    ticks = [{"x": round(STRIP_PAD + k / 4 * span, 2), "label": f"{t1 * k / 4:.0f}"} for k in range(5)]

    switch = view.declared.model_switch  # the option that turns the model on: named when none answered
    return {
        "switch": switch,
        "switch_value": as_dict(view.config.get("options")).get(switch) if switch else None,
        "profile": _velocity_profile(view),
        "verdicts": verdicts,
        "marks": marks,
        "ticks": ticks,
        "states": profile.states,
        "samples": len(profile.t),
    }


def run_context(view: RunView) -> dict[str, Any]:
    """Everything the run template needs."""
    raw = as_dict(view.config.get("options")).get("obstacles")
    added = [(p[0], p[1]) for p in (as_pose(o) for o in (raw if isinstance(raw, list) else [])) if p is not None]
    scenario = view.scenario
    if scenario is not None and added:
        # deferred: numpy (about 0.1 s) loads only for a run with added obstacles
        from llmnav.mapping.targets import with_added_obstacles

        scenario = with_added_obstacles(scenario, added)  # the boxes dropped with --obstacle
    ends = [view.trajectory[0], view.trajectory[-1]] if view.trajectory else []
    base = draw_base_map(
        scenario,
        *page_size(scenario),
        trajectory=view.trajectory,
        targets=view.targets,
        radius_m=view.success_radius_m,
        markers=ends,  # the page's start and end circles: object names are placed clear of them
    )
    trajectory = view.trajectory
    images = {h: data_uri(p, view.run_dir) for h, p in view.image_files.items()}
    metre = base.metre_px
    return {
        "generator": GENERATOR,
        "view": view,
        "header": view.header,
        "map": {
            "src": "data:image/png;base64," + base64.b64encode(base.png()).decode("ascii"),
            "width": base.width,
            "height": base.height,
            "transform": f"matrix({base.sx:.4f} 0 0 {base.sy:.4f} {base.ox:.2f} {base.oy:.2f})",
            "marker_m": round(7.0 / metre, 3),  # [m] a 7-pixel marker at the picture's scale
        },
        "trajectory": points_attr(trajectory) if len(trajectory) > 1 else None,
        "start": svg_point(*trajectory[0][:2]) if trajectory else None,
        "end": svg_point(*trajectory[-1][:2]) if trajectory else None,
        "oracle": points_attr(view.oracle) if view.oracle else None,
        "markers": [m for m in (_marker(s) for s in view.steps) if m is not None],
        "overlays": [_overlay(s) for s in view.steps],
        "images": images,
        "lidar": {s.index: lidar_wedges(s.lidar) for s in view.steps if s.lidar is not None},
        "velocity": _velocity_charts(view),
    }


def run_page(run_dir: Path) -> str:
    """The HTML page of one run folder."""
    return environment().get_template("run.html.j2").render(**run_context(build_run_view(run_dir)))


# --- the sweep page ------------------------------------------------------------------------------


def _href(target: Path, page: Path) -> str:
    """A relative link that stays a path whatever the folder names hold (`:`, `#`, `?`, spaces).

    The `./` prefix keeps a folder named like `javascript:...` from being read as a URL scheme.
    """
    relative = Path(os.path.relpath(target.resolve(), page.parent.resolve())).as_posix()
    return quote(relative if relative.startswith("../") else "./" + relative)


def _bar(value: float | None, low: float | None, high: float | None) -> dict[str, Any]:
    """One bar on a 0–1 scale as CSS percentages: its length and its interval's whisker."""
    if value is None:
        return {"value": None}
    low = value if low is None or low != low else low  # nan: no interval (n = 1)
    high = value if high is None or high != high else high
    return {"value": value, "width": round(100 * value, 2), "left": round(100 * low, 2),
            "span": round(100 * (high - low), 2)}  # fmt: skip


def _charts(runs: list[Run], keys: list[str]) -> list[dict[str, Any]]:
    """Per task, one bar per condition: mean score ± SD and success rate with Wilson's 95 % interval.

    HTML, not a picture: each condition's label is text in its own row, wrapped to the column's width, so
    long labels (a backend URL, several factors) never run into each other, and a reader can copy them.
    """
    # deferred: scoring brings pydantic and yaml (about 0.15 s), only for a sweep's page
    from llmnav.scoring.score import UNIT_RANGE, group_runs

    by_task: dict[str, list[dict[str, Any]]] = {}
    for task, label, group in group_runs(runs, keys):
        scores = [float(r.summary["score"]) for r in group if isinstance(r.summary.get("score"), (int, float))]
        d = describe(scores)
        sd = d.sd if d.n > 1 else 0.0
        score_low, score_high = clip_interval(d.mean - sd, d.mean + sd, UNIT_RANGE) if d.n else (None, None)
        ok = sum(1 for r in group if r.summary.get("success"))
        rate_low, rate_high = wilson_interval(ok, len(group))
        by_task.setdefault(task, []).append(
            {
                "label": label,
                "n": len(group),
                "score": _bar(d.mean if d.n else None, score_low, score_high) | {"sd": sd, "n": d.n},
                "rate": _bar(ok / len(group), rate_low, rate_high) | {"ok": ok, "low": rate_low, "high": rate_high},
            }
        )
    return [{"title": task, "bars": bars} for task, bars in by_task.items()]


def _success_maps(runs: list[Run], keys: list[str], links: dict[Path, str]) -> list[dict[str, Any]]:
    """Per condition: a task × start-pose grid of successes, each cell linking to its runs' pages."""
    # deferred: scoring brings pydantic and yaml (about 0.15 s), only for a sweep's page
    from llmnav.scoring.score import group_runs

    conditions: dict[str, dict[str, list[Run]]] = {}
    for task, label, group in group_runs(runs, keys):  # tasks in the tables' order
        conditions.setdefault(label, {})[task] = group
    maps = []
    for label, by_task in conditions.items():
        every = [r for group in by_task.values() for r in group]
        poses = sorted({r.summary.get("start_pose_index") for r in every}, key=lambda p: (p is None, p or 0))
        rows = []
        for task, group in by_task.items():
            cells = []
            for pose in poses:
                here = [r for r in group if r.summary.get("start_pose_index") == pose]
                ok = sum(1 for r in here if r.summary.get("success"))
                cells.append(
                    {
                        "n": len(here),
                        "ok": ok,
                        "rate": ok / len(here) if here else None,
                        "runs": [
                            {"href": links[r.run_dir], "outcome": r.summary.get("outcome"), "name": r.run_dir.name}
                            for r in here
                        ],
                    }
                )
            rows.append({"task": task, "cells": cells})
        maps.append({"condition": label, "poses": poses, "rows": rows})
    return maps


def sweep_context(root: Path, out: Path, *, make_run_pages: bool = True) -> dict[str, Any]:
    """Everything the sweep template needs; writes the run pages that are missing."""
    # deferred: llmnav.ablate and scoring bring pydantic and yaml (about 0.15 s), only for a sweep's page
    from llmnav.ablate import MANIFEST_FILE
    from llmnav.runs.folders import read_runs, split_aborted
    from llmnav.scoring.score import varying_keys
    from llmnav.scoring.tables import build_tables

    runs, broken = read_runs([root])  # a damaged run is named on the page, not fatal to it
    keys = varying_keys(runs)
    links: dict[Path, str] = {}
    for run in runs:
        page = run.run_dir / PAGE_FILE
        if make_run_pages and not is_our_page(page):  # missing, or a link or file planted under its name
            write_page(run_page(run.run_dir), page)
        links[run.run_dir] = _href(page, out)
    manifest: dict[str, Any] = {}
    try:
        loaded = bounded_loads(read_bytes(root / MANIFEST_FILE, limit=SUMMARY_LIMIT, root=root))
        manifest = loaded if isinstance(loaded, dict) else {}
    except (OSError, ValueError, UnsafeFileError):
        manifest = {}
    tables: list[Table] = build_tables(runs, keys)
    return {
        "generator": GENERATOR,
        "name": manifest.get("name") or root.resolve().name,
        "manifest": manifest,
        "root": str(root),
        "keys": keys,
        "tables": tables,
        "charts": _charts(split_aborted(runs)[0], keys),  # infrastructure failures are in no mean
        "maps": _success_maps(runs, keys, links),
        "runs": [
            {
                "href": links[r.run_dir],
                "name": r.run_dir.name,
                "task": r.task,
                "pose": r.summary.get("start_pose_index"),
                "condition": ", ".join(f"{k}={r.condition.get(k)}" for k in keys) or "all",
                "outcome": r.summary.get("outcome"),
                "score": r.summary.get("score"),
                "success": r.summary.get("success"),
                "cut_short": r.summary.get("cut_short"),
            }
            for r in runs
        ],
        "broken": broken,
        "errors": [e for e in manifest.get("episodes") or [] if isinstance(e, dict) and e.get("status") == "error"],
    }


def sweep_page(root: Path, out: Path) -> str:
    """The HTML page of a sweep (an ablation folder, or any folder of run folders)."""
    return environment().get_template("sweep.html.j2").render(**sweep_context(root, out))


# --- writing -------------------------------------------------------------------------------------


def run_own_file(path: Path) -> str | None:
    """What `path` is when it is a file a run or a sweep keeps (its log, summary, images, lock), else None.

    Those are never replaced by a page or a video, --force or not.
    """
    # deferred: llmnav.ablate brings pydantic and yaml (about 0.15 s), only when a page is written
    from llmnav.ablate import MANIFEST_FILE

    target = path.absolute()
    folder = target.parent
    if folder.name == IMAGES_DIR and (folder.parent / RUN_FILE).exists():
        return f"an image of the run {folder.parent}"
    own = {RUN_FILE, RUN_FILE + ".tmp", SUMMARY_FILE, SUPERSEDED_FILE, LOCK_FILE, MANIFEST_FILE, PROFILE_FILE}
    if target.name in own | {"trajectory.png"} and ((folder / RUN_FILE).exists() or (folder / MANIFEST_FILE).exists()):
        return f"the {target.name} of {folder}"
    return None


def check_target(out: Path, flag: str, *, force: bool = False, ours: Callable[[Path], bool] = is_our_page) -> None:
    """Refuse `out` before any work: a folder, a run's own file, or (unless forced) a file llmnav did not write."""
    if out.is_dir():
        raise BadInputError(f"{flag} {out}: is a folder; give a file name")
    own = run_own_file(out)
    if own is not None:
        raise BadInputError(f"{flag} {out}: that is {own}; llmnav never replaces it, choose another file")
    if os.path.lexists(out) and not force and not ours(out):
        raise BadInputError(f"{flag} {out}: exists and was not written by llmnav view; use --force to replace it")


def check_out(out: Path, *, force: bool = False) -> None:
    """`check_target` of a page's --out."""
    check_target(out, "--out", force=force)


def write_page(html: str, out: Path) -> Path:
    """Write a page atomically (a fresh temporary file renamed into place; a link at `out` is replaced)."""
    out = Path(out)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        write_text(out, html)
    except OSError as err:
        raise BadInputError(f"--out {out}: cannot write: {err.strerror or err}") from None
    return out
