"""The package's rooms: no import cycles (type-only imports included) and a top level that shows only its face."""

from __future__ import annotations

import shutil
from pathlib import Path

import grimp

ROOT = Path(__file__).resolve().parents[1]
TOP_LEVEL = {"__init__", "cli", "errors", "testing"}  # the package face, the CLI, the errors, the plug-in kit


def cycles(package: str) -> list[list[str]]:
    """Strongly connected groups of more than one module in `package`'s import graph (Tarjan, iterative)."""
    graph = grimp.build_graph(package, include_external_packages=False, exclude_type_checking_imports=False)
    edges = {m: sorted(graph.find_modules_directly_imported_by(m)) for m in sorted(graph.modules)}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    for root in edges:
        if root in index:
            continue
        work = [(root, 0)]
        while work:
            node, i = work.pop()
            if i == 0:
                index[node] = low[node] = len(index)
                stack.append(node)
                on_stack.add(node)
            targets = edges[node]
            if i < len(targets):
                work.append((node, i + 1))
                nxt = targets[i]
                if nxt not in index:
                    work.append((nxt, 0))
                elif nxt in on_stack:
                    low[node] = min(low[node], index[nxt])
                continue
            if low[node] == index[node]:
                group = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    group.append(member)
                    if member == node:
                        break
                if len(group) > 1:
                    found.append(sorted(group))
            if work:
                parent = work[-1][0]
                low[parent] = min(low[parent], low[node])
    return found


def test_no_import_cycles() -> None:
    assert cycles("llmnav") == []


def test_the_cycle_count_sees_a_planted_cycle(tmp_path: Path, monkeypatch) -> None:
    # The count can fail: a copy of the package where a leaf imports, under TYPE_CHECKING only, what imports it.
    package = tmp_path / "llmnav"
    shutil.copytree(ROOT / "llmnav", package, ignore=shutil.ignore_patterns("__pycache__", "_data"))
    leaf = package / "core" / "geometry.py"
    planted = "\nfrom typing import TYPE_CHECKING\n\nif TYPE_CHECKING:\n    import llmnav.core.chat\n"
    leaf.write_text(leaf.read_text() + planted)
    chat = package / "core" / "chat.py"
    chat.write_text(chat.read_text() + "\nimport llmnav.core.geometry  # noqa: E402,F401\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    for name in [m for m in __import__("sys").modules if m == "llmnav" or m.startswith("llmnav.")]:
        monkeypatch.delitem(__import__("sys").modules, name)
    assert ["llmnav.core.chat", "llmnav.core.geometry"] in cycles("llmnav")


def test_the_top_level_holds_only_the_package_face() -> None:
    loose = {p.stem for p in (ROOT / "llmnav").glob("*.py")}
    assert loose <= TOP_LEVEL, f"modules loose at the top of llmnav/: {sorted(loose - TOP_LEVEL)}"
