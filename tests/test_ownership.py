"""A planner owns everything about itself: no shared room names a planner, or a flag or option only one
planner has.

The shared rooms are `commands/`, `guard/`, `scoring/` and `view/`. What counts as naming is read from the
planners themselves (their registered names, declared `cli_flags` and own options), never listed here, so
a planner added tomorrow is covered too. Only code is read: docstrings and comments may explain a planner.
"""

from __future__ import annotations

import ast
from collections import Counter
from collections.abc import Iterator
from pathlib import Path

from llmnav.backends.policy import POLICIES
from llmnav.planners.base import planner_class, usable_planner_names
from llmnav.planners.options import DriveOptions

PACKAGE = Path(__file__).parents[1] / "llmnav"
SHARED_ROOMS = ("commands", "guard", "scoring", "view")

# Strings that equal a single planner's option key but mean something else where they appear. Each entry
# is (file under llmnav/, string): reviewed, with the reason beside it.
OTHER_MEANINGS = {
    ("scoring/cost.py", "prompt"): "a token count's kind (prompt vs completion tokens), not the stepwise prompt",
    ("scoring/papers.py", "assist"): "the FSM source's own tables (fsm-compare, fsm-velocity) group by its factor",
    ("scoring/metrics.py", "explore"): "a task's kind (explore: no target), not the hybrid's exploration option",
    ("scoring/score.py", "explore"): "a task's kind",
    ("scoring/papers.py", "explore"): "a task's kind",
    ("scoring/metrics.py", "localize"): "the navigation layer's localizer event in the run log",
}


def planner_words() -> tuple[set[str], set[str], set[str]]:
    """(planner names, single-planner flags, single-planner option keys), from the registry.

    A planner name that is also an answer policy's (`oracle`: the oracle planner, and `policy:oracle`
    answers) is left out: the shared rooms must tell oracle answers apart from models.
    """
    names = set(usable_planner_names()) - set(POLICIES)
    owners: Counter[str] = Counter()
    flags: Counter[str] = Counter()
    for name in usable_planner_names():
        options = planner_class(name).Options
        owners.update(set(options.model_fields) - set(DriveOptions.model_fields))
        flags.update({f.flag for f in options.cli_flags})
    single_keys = {key for key, n in owners.items() if n == 1}
    single_flags = {flag for flag, n in flags.items() if n == 1}
    return names, single_flags, single_keys


def code_strings(source: str) -> Iterator[tuple[int, str]]:
    """(line, text) of every string constant in `source` that is not a docstring."""
    tree = ast.parse(source)
    docstrings = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant):
                docstrings.add(id(first.value))
    strings = [
        (node.lineno, node.col_offset, node.value)
        for node in ast.walk(tree)
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docstrings
    ]
    for line, _column, text in sorted(strings):
        yield line, text


def namings(relative: str, source: str, words: tuple[set[str], set[str], set[str]]) -> list[str]:
    """Every place in one module's code that names a planner, one of its flags or one of its own options."""
    names, flags, keys = words
    found = []
    for line, text in code_strings(source):
        if text in names:
            found.append(f"{relative}:{line}: planner name {text!r}")
        if text in keys and (relative, text) not in OTHER_MEANINGS:
            found.append(f"{relative}:{line}: option {text!r} of a single planner")
        found += [f"{relative}:{line}: flag {flag} of a single planner" for flag in flags if flag in text]
    return found


def test_the_registry_gives_words_to_look_for() -> None:
    # Without them the check below would pass on anything.
    names, flags, keys = planner_words()
    assert {"stepwise", "waypoints", "fsm", "hybrid"} <= names
    assert {"--assist", "--prompt", "--menu-order"} <= flags
    assert {"assist", "explore", "prompt"} <= keys


def test_no_shared_room_names_a_planner_or_its_flags() -> None:
    words = planner_words()
    found = []
    for room in SHARED_ROOMS:
        for path in sorted((PACKAGE / room).rglob("*.py")):
            relative = path.relative_to(PACKAGE).as_posix()
            found += namings(relative, path.read_text(encoding="utf-8"), words)
    assert not found, "\n".join(found)


def test_every_other_meaning_is_still_there() -> None:
    # An entry whose string left its file is stale: it would excuse the next real naming.
    for (relative, text), _why in OTHER_MEANINGS.items():
        strings = {found for _line, found in code_strings((PACKAGE / relative).read_text(encoding="utf-8"))}
        assert text in strings, relative


def test_the_check_finds_a_planted_naming() -> None:
    # The checker can fail: a planner name, a flag in help text and a single planner's option, in code.
    words = ({"hybrid"}, {"--assist"}, {"explore"})
    source = (
        '"""Docstrings may say hybrid."""\n'
        "def pick(run):  # comments may say hybrid too\n"
        '    if run["planner"] == "hybrid":\n'
        '        return run["explore"]\n'
        '    return f"see --assist for {run}"\n'
    )
    found = namings("view/planted.py", source, words)
    assert found == [
        "view/planted.py:3: planner name 'hybrid'",
        "view/planted.py:4: option 'explore' of a single planner",
        "view/planted.py:5: flag --assist of a single planner",
    ]
