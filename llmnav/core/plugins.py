"""Plugins: the planners and backends that installed distributions register as entry points.

Every `llmnav.planners` and `llmnav.backends` entry point, llmnav's own included, is found here:
- once per process and group: scanning the installed distributions takes about 12 ms, and a grid of
  20,000 episodes asked for it several times an episode. The scan is repeated only when `sys.path`
  changes (a test putting a plugin on the path, a `pip install --target` onto it);
- never silently replaced: a name registered by two distributions (a plugin calling itself `hybrid`, or
  two plugins one name) is refused wherever it is asked for, naming both, since which one Python would
  load depends on path order;
- with where it came from: `Plugin.source` ("llmnav 0.1.0") is what a run log records;
- one at a time: a plugin that fails to import, or is not the class its group takes, is reported as
  broken by `broken` and left out of every listing of usable names, so it troubles only a command that
  asks for it by name.

A plugin is code running inside llmnav's process, with all the access that gives: installing one is
trusting its author like any other dependency.
"""

from __future__ import annotations

import sys
import threading
from collections.abc import Callable
from dataclasses import dataclass
from importlib import metadata
from importlib.metadata import EntryPoint
from typing import Any

from llmnav.errors import BadInputError


@dataclass(frozen=True)
class Plugin:
    """One entry point: its name, its target and the distribution that registered it."""

    name: str
    value: str  # "module:attribute"
    distribution: str
    version: str
    entry_point: EntryPoint

    @property
    def source(self) -> str:
        """The distribution and version that supply it ("llmnav 0.1.0")."""
        return f"{self.distribution} {self.version}"

    def load(self) -> Any:
        """Import the target (exceptions of a broken plugin propagate)."""
        return self.entry_point.load()


def _plugin(point: EntryPoint) -> Plugin:
    dist = point.dist
    name = (dist.metadata["Name"] if dist is not None else None) or "an unknown distribution"
    version = (dist.version if dist is not None else None) or "?"
    return Plugin(point.name, point.value, name, version, point)


_LOCK = threading.Lock()
_SCANS: dict[str, tuple[tuple[Any, ...], dict[str, tuple[Plugin, ...]]]] = {}  # group → (environment, by name)
_LOADED: dict[tuple[str, str, str], tuple[Any, str | None]] = {}  # (group, name, value) → (object, problem)


def registrations(group: str) -> dict[str, tuple[Plugin, ...]]:
    """Every registration in `group` by name (two or more under one name: a clash), scanned once."""
    # what the scan depends on: the path it searches, and the scanner (tests replace it)
    environment = (*sys.path, metadata.entry_points)
    with _LOCK:
        cached = _SCANS.get(group)
        if cached is not None and cached[0] == environment:
            return cached[1]
    found: dict[str, list[Plugin]] = {}
    for point in metadata.entry_points(group=group):
        plugin = _plugin(point)
        same = found.setdefault(point.name, [])
        if all((p.distribution, p.value) != (plugin.distribution, plugin.value) for p in same):
            same.append(plugin)
    by_name = {name: tuple(plugins) for name, plugins in found.items()}
    with _LOCK:
        if cached is not None:  # the environment changed: a name may now load something else
            _LOADED.clear()
        _SCANS[group] = (environment, by_name)
    return by_name


def forget() -> None:
    """Scan again on the next look-up (tests that install or remove plugins)."""
    with _LOCK:
        _SCANS.clear()
        _LOADED.clear()


def clash_message(kind: str, name: str, plugins: tuple[Plugin, ...]) -> str:
    """The one line refusing a name two distributions register."""
    who = " and ".join(f"{p.source} ({p.value})" for p in plugins)
    return f"{kind} '{name}' is registered by {who}: uninstall one (a plugin never replaces another silently)"


def find(group: str, kind: str, name: str) -> Plugin:
    """The plugin registered as `name`; BadInputError when none is or when two distributions are."""
    every = registrations(group)
    plugins = every.get(name)
    if not plugins:
        raise BadInputError(f"unknown {kind} '{name}' (registered: {', '.join(sorted(every))})")
    if len(plugins) > 1:
        raise BadInputError(clash_message(kind, name, plugins))
    return plugins[0]


def load(group: str, kind: str, name: str, check: Callable[[Any], str | None]) -> Any:
    """The object `name` names, loaded once; BadInputError (one line) when unknown, clashing or broken.

    `check` returns why a loaded object is not what the group takes (None when it is).
    """
    plugin = find(group, kind, name)
    key = (group, name, plugin.value)
    with _LOCK:
        done = _LOADED.get(key)
    if done is None:
        try:
            target = plugin.load()
            done = (target, check(target))
        except Exception as err:  # noqa: BLE001 - a broken third-party plugin: one line, not a traceback
            text = str(err).strip().splitlines()
            done = (None, f"failed to load: {type(err).__name__}" + (f": {text[0]}" if text else ""))
        with _LOCK:
            _LOADED[key] = done
    target, problem = done
    if problem is not None:
        raise BadInputError(f"{kind} '{name}' from {plugin.source} {problem}")
    return target


def usable(group: str, kind: str, check: Callable[[Any], str | None]) -> list[str]:
    """The names in `group` that load and pass `check`, sorted: what listings and loops over all use."""
    return sorted(name for name in registrations(group) if not problem_of(group, kind, name, check))


def broken(group: str, kind: str, check: Callable[[Any], str | None]) -> dict[str, str]:
    """Each name that clashes, fails to load or fails `check`, with its one-line problem."""
    found = {name: problem_of(group, kind, name, check) for name in registrations(group)}
    return {name: problem for name, problem in sorted(found.items()) if problem}


def problem_of(group: str, kind: str, name: str, check: Callable[[Any], str | None]) -> str | None:
    """Why `name` cannot be used (None when it can)."""
    try:
        load(group, kind, name, check)
    except BadInputError as err:
        return str(err)
    return None
