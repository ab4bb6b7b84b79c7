"""Resuming an ablation: which folder holds each episode's result, and where an unfinished one runs again.

Nothing here deletes anything. An episode's folders are `<dir_name>`, `<dir_name>.2`, `<dir_name>.3`, ...
A folder is this episode's only when its config line carries the episode's condition hash; a folder of
another condition (another model, seed, option, scenario file or prompt) is left alone and the episode
takes the next free name. A folder of this episode that holds no result (cut short, aborted by a backend
failure, or unreadable) is kept, marked with `superseded.json` (which `llmnav score` skips when it scans
a folder), and the episode runs again into the next free name.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from llmnav.ablate.grid import Episode
from llmnav.ablate.manifest import is_result
from llmnav.core.safefiles import LOG_LIMIT, SUMMARY_LIMIT, UnsafeFileError, loads, read_bytes
from llmnav.errors import BadInputError, FolderLockedError, one_line
from llmnav.runs.locking import locked_by
from llmnav.runs.runlog import RUN_FILE, SUMMARY_FILE, SUPERSEDED_FILE, read_run, write_json_atomic

_CONFIG_LINE_LIMIT = 4 << 20  # bytes: a config line is a few kB; more is damage, not a config


@dataclass
class Located:
    """Where an episode stands: the folder to use, its result if finished, and folders set aside."""

    dir_name: str
    summary: dict[str, Any] | None
    kept: list[tuple[str, str]]  # (folder, why): this episode's folders found now holding no result
    earlier: list[str]  # "folder: why" of this episode's folders set aside by an earlier run


def _read_config(run_dir: Path) -> dict[str, Any] | str:
    """The config line of a run folder, or why it cannot be read."""
    try:
        raw = read_bytes(run_dir / RUN_FILE, limit=LOG_LIMIT, root=run_dir).split(b"\n", 1)[0]
    except FileNotFoundError:
        return f"no {RUN_FILE}"
    except OSError as err:
        return f"cannot read {RUN_FILE}: {err.strerror or err}"
    except UnsafeFileError as err:
        return one_line(err).removeprefix(f"{run_dir}/")
    if len(raw) > _CONFIG_LINE_LIMIT:
        return f"{RUN_FILE} is damaged (its first line is over {_CONFIG_LINE_LIMIT} bytes)"
    try:
        config = loads(raw)
    except (UnicodeDecodeError, json.JSONDecodeError):
        return f"{RUN_FILE} is damaged (its first line is not a JSON configuration)"
    if not isinstance(config, dict) or config.get("type") != "config":
        return f"{RUN_FILE} is damaged (its first line is not the run configuration)"
    return config


def _read_json(path: Path) -> dict[str, Any]:
    try:
        data = loads(read_bytes(path, limit=SUMMARY_LIMIT, root=path.parent))
    except (OSError, UnsafeFileError, UnicodeDecodeError, json.JSONDecodeError):
        return {}
    return data if isinstance(data, dict) else {}


def _read_summary(run_dir: Path) -> dict[str, Any] | str:
    try:
        summary = loads(read_bytes(run_dir / SUMMARY_FILE, limit=SUMMARY_LIMIT, root=run_dir))
    except FileNotFoundError:
        return "cut short (no summary)"
    except (OSError, UnsafeFileError, UnicodeDecodeError, json.JSONDecodeError):
        return f"{SUMMARY_FILE} is damaged"
    if not isinstance(summary, dict) or "outcome" not in summary:
        return f"{SUMMARY_FILE} is damaged (no outcome)"
    return summary


def inspect(run_dir: Path, ep: Episode) -> tuple[str, dict[str, Any] | None, str]:
    """("done" | "retry" | "other", summary when done, why) for one existing folder."""
    config = _read_config(run_dir)
    if isinstance(config, str):
        return "retry", None, config
    if config.get("condition_hash") != ep.identity:
        return "other", None, "another condition"
    summary = _read_summary(run_dir)
    if isinstance(summary, str):
        return "retry", None, summary
    reason = str(summary.get("reason") or "")
    if summary.get("cut_short") or reason.startswith(("crash", "interrupted")):
        return "retry", None, f"cut short ({reason or 'no end'})"
    if not is_result(summary):
        return "retry", None, f"{summary.get('outcome')}: {reason or 'no reason logged'}"
    try:  # the whole log, not just its first line: a result whose log was damaged is not kept as one
        complete = read_run(run_dir).complete
    except BadInputError as err:
        return "retry", None, f"{RUN_FILE} is damaged ({one_line(err).removeprefix(f'{run_dir / RUN_FILE}: ')})"
    if not complete:
        return "retry", None, f"{RUN_FILE} is damaged (no end event)"
    return "done", summary, ""


def locate(ep: Episode, root: Path) -> Located:
    """Find the episode's finished run under `root`, or the free folder name to run it into."""
    kept: list[tuple[str, str]] = []
    earlier: list[str] = []
    n = 1
    while True:
        name = ep.dir_name if n == 1 else f"{ep.dir_name}.{n}"
        n += 1
        path = root / name
        if not path.exists():
            return Located(name, None, kept, earlier)
        if not path.is_dir():
            continue
        if (path / SUPERSEDED_FILE).exists():
            mark = _read_json(path / SUPERSEDED_FILE)
            if mark.get("episode") == ep.key:
                earlier.append(f"{name}: {mark.get('reason')}")
            continue
        holder = locked_by(path)
        if holder is not None:
            raise FolderLockedError(f"{path} is in use: {holder} is writing this run folder")
        state, summary, why = inspect(path, ep)
        if state == "done":
            return Located(name, summary, kept, earlier)
        if state == "retry":
            kept.append((name, why))


def set_aside(root: Path, kept: list[tuple[str, str]], episode_key: str, replaced_by: str) -> None:
    """Mark each kept folder as superseded (nothing in it is changed or removed)."""
    for name, why in kept:
        write_json_atomic(
            root / name / SUPERSEDED_FILE,
            {"episode": episode_key, "reason": why, "replaced_by": replaced_by},
        )
