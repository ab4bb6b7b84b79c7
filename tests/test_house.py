"""The package's rooms: no import cycles (type-only imports included), a top level that shows only its face, and
an import inside a function only where it defers a heavy dependency, with a comment saying so."""

from __future__ import annotations

import ast
import io
import re
import shutil
import tokenize
from pathlib import Path

import grimp

ROOT = Path(__file__).resolve().parents[1]
TOP_LEVEL = {"__init__", "cli", "errors", "testing"}  # the package face, the CLI, the errors, the plug-in kit
# Comments that explain nothing: linter and formatter pragmas.
PRAGMA = re.compile(r"noqa(:\s*[A-Z0-9, ]+)?|type:\s*ignore(\[[^\]]*\])?|pragma:[^#]*|fmt:\s*\w+")


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


def uncommented_imports(source: str) -> list[int]:
    """Lines of the imports inside functions that no comment explains.

    A comment explains an import on the import's own lines, or on the line directly above it or above the
    first of the imports it follows (blank lines may separate those: isort's groups). Pragmas (`# noqa`,
    `# type: ignore`) explain nothing.
    """
    lines = source.splitlines()
    comments: dict[int, str] = {}
    for token in tokenize.generate_tokens(io.StringIO(source).readline):
        if token.type == tokenize.COMMENT:
            comments[token.start[0]] = token.string
    explaining = {n for n, text in comments.items() if re.search(r"[A-Za-z]{2}", PRAGMA.sub("", text.lstrip("#")))}
    comment_lines = {n for n in explaining if lines[n - 1].lstrip().startswith("#")}

    def explained(statements: list[ast.stmt], i: int) -> bool:
        node = statements[i]
        if explaining & set(range(node.lineno, (node.end_lineno or node.lineno) + 1)):
            return True
        above = node.lineno - 1
        while above > 0 and not lines[above - 1].strip():
            above -= 1
        if above in comment_lines and above == node.lineno - 1:
            return True
        previous = statements[i - 1] if i > 0 else None
        if isinstance(previous, ast.Import | ast.ImportFrom) and previous.end_lineno == above:
            return explained(statements, i - 1)
        return False

    found: set[int] = set()
    for function in ast.walk(ast.parse(source)):
        if not isinstance(function, ast.FunctionDef | ast.AsyncFunctionDef):
            continue
        for node in ast.walk(function):
            for field in ("body", "orelse", "finalbody"):
                statements = getattr(node, field, None)
                if not isinstance(statements, list):
                    continue
                for i, statement in enumerate(statements):
                    if isinstance(statement, ast.Import | ast.ImportFrom) and not explained(statements, i):
                        found.add(statement.lineno)
    return sorted(found)


def test_imports_inside_functions_say_what_they_defer() -> None:
    found: list[str] = []
    for path in sorted((ROOT / "llmnav").rglob("*.py")):
        name = path.relative_to(ROOT).as_posix()
        found += [f"{name}:{line}" for line in uncommented_imports(path.read_text())]
    assert not found, "imports inside functions with no comment saying what they defer and why:\n" + "\n".join(found)


def test_the_import_comment_check_flags_an_uncommented_import() -> None:
    # The check can fail: a function-level import with no comment is named, a commented block is not.
    source = (
        "import sys\n"  # 1 module level: not checked
        "\n"
        "def f():\n"
        "    import json\n"  # 4 flagged
        "\n"
        "    if json:\n"
        "        # deferred: numpy loads only when f runs\n"
        "        import numpy\n"
        "        import scipy\n"
        "\n"
        "        from llmnav import cli\n"  # 11 the same block, after isort's blank line
        "    import os  # noqa: F401\n"  # 12 flagged: a pragma explains nothing
        "    import re  # deferred: a test\n"
        "\n"
        "class C:\n"
        "    import math\n"  # 16 a class body: not checked
        "\n"
        "    def g(self):\n"
        "        def h():\n"
        "            import csv\n"  # 20 flagged: nested functions too
    )
    assert uncommented_imports(source) == [4, 12, 20]
