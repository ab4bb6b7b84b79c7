"""Print the reliability table from the counters the suite wrote (tests/reliability/conftest.py).

Usage: python tests/reliability/report.py [COUNTERS.json]   (default .pytest_cache/reliability.json)
Exit status 1 when any category shows failures, unsafe motions, lost logs, leaked keys or crashes.
"""

from __future__ import annotations

import io
import json
import sys
from pathlib import Path
from typing import Any

DEFAULT = Path(__file__).parents[2] / ".pytest_cache" / "reliability.json"
PLANNERS = ["stepwise", "waypoints", "hybrid", "fsm", "oracle", "frontier"]
ORDER = [
    *(f"fuzz: {p}" for p in PLANNERS),
    "backend faults",
    "crash safety",
    "data safety",
    "worker kill",
    "hostile folders",
    "hostile sizes",
    "servers",
    "serve bounds",
    "hostile replies",
    "hostile plugins",
    "raw access",
    "honest accounting",
    "crashed runs",
    "mode fallback",
    "scoring scripts",
    "bad input",
    "secrets",
    "fsm deadline",
    "dead assist",
]
# Categories whose "logs lost" count results lost or mislabelled: concurrent sweeps, resumes, kills.
RESULT_CATEGORIES = ("data safety",)
BAD_FIELDS = ("failures", "unsafe", "lost", "leaked", "crashes")


def _note_text(notes: dict[str, Any]) -> str:
    parts = []
    for key, value in notes.items():
        if isinstance(value, list):
            value = ", ".join(map(str, value))
        elif isinstance(value, float):
            value = f"{value:.3g}"
        parts.append(f"{key}: {value}")
    return "; ".join(parts)


def render(data: dict[str, Any], width: int = 160) -> str:
    """The table as text (rich, no colour codes when not on a terminal)."""
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    counts: dict[str, dict[str, int]] = data.get("counts", {})
    notes: dict[str, dict[str, Any]] = data.get("notes", {})
    categories = [c for c in ORDER if c in counts] + [c for c in counts if c not in ORDER]
    title = "llmnav reliability (" + ("full run" if data.get("full") else "quick subset") + ")"
    table = Table(title=title, show_lines=False)
    for name, justify in [
        ("category", "left"),
        ("cases tried", "right"),
        ("failures", "right"),
        ("unsafe motions", "right"),
        ("logs lost", "right"),
        ("leaked keys", "right"),
        ("crashes", "right"),
        ("details", "left"),
    ]:
        table.add_column(name, justify=justify, overflow="fold")  # type: ignore[arg-type]
    totals = dict.fromkeys(["tried", *BAD_FIELDS], 0)
    for category in categories:
        row = counts[category]
        for key in totals:
            totals[key] += int(row.get(key, 0))
        table.add_row(
            escape(category),
            f"{row.get('tried', 0):,}",
            *(str(row.get(k, 0)) for k in ("failures", "unsafe", "lost", "leaked", "crashes")),
            escape(_note_text(notes.get(category, {}))),
        )
    table.add_section()
    table.add_row(
        "total", f"{totals['tried']:,}", *(str(totals[k]) for k in BAD_FIELDS), "", style="bold"
    )
    buffer = io.StringIO()
    Console(file=buffer, width=width, force_terminal=False, color_system=None).print(table)
    verdict = "PASS" if not any(totals[k] for k in BAD_FIELDS) else "FAIL"
    rows = [counts[c] for c in RESULT_CATEGORIES if c in counts]
    results = ""
    if rows:
        lost = sum(int(r.get("lost", 0)) + int(r.get("failures", 0)) for r in rows)
        tried = sum(int(r.get("tried", 0)) for r in rows)
        results = f"results lost or mislabelled: {lost} (over {tried} concurrency, resume and kill cases)\n"
    return buffer.getvalue() + results + f"reliability: {verdict}\n"


def bad(data: dict[str, Any]) -> bool:
    """Whether any category reports a problem."""
    return any(int(row.get(k, 0)) for row in data.get("counts", {}).values() for k in BAD_FIELDS)


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    path = Path(args[0]) if args else DEFAULT
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as err:
        print(f"error: cannot read reliability counters {path}: {err}", file=sys.stderr)
        return 2
    sys.stdout.write(render(data))
    return 1 if bad(data) else 0


if __name__ == "__main__":
    sys.exit(main())
