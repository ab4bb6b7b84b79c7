"""Scenario suites for sweeps: `generated:KIND:N[:FIRST_SEED]` or a folder of scenario files.

`generated:flat:100` is the flats of seeds 0..99 (`generated:flat:100:500`: seeds 500..599), written once
into a folder the caller names; as generation is exact, a second sweep finds the same bytes there and
resumes. A file that differs from what its seed gives (edited since) is refused, never overwritten.
"""

from __future__ import annotations

import re
from pathlib import Path

from llmnav.buildings.generate import Request, generate_suite
from llmnav.core.safefiles import write_text
from llmnav.errors import BadInputError
from llmnav.world.scenario import list_scenarios

_GENERATED = re.compile(r"generated:([A-Za-z]+):([0-9]{1,6})(?::([0-9]{1,18}))?")


def is_suite(text: str) -> bool:
    """Whether a `--scenario` value names a suite rather than one scenario (a bundled name never does)."""
    return text.startswith("generated:") or (Path(text).is_dir() and text not in list_scenarios())


def suite_files(text: str, folder: Path) -> list[Path]:
    """The scenario files of a suite, in order; generated ones are written to `folder` first."""
    if not text.startswith("generated:"):
        files = sorted(p for p in Path(text).glob("*.yaml") if p.is_file())
        if not files:
            raise BadInputError(f"--scenario {text}: a folder without scenario files (*.yaml)")
        return files
    match = _GENERATED.fullmatch(text)
    if match is None:
        raise BadInputError(f"--scenario {text}: expected generated:KIND:N or generated:KIND:N:FIRST_SEED")
    kind, count, first = match.group(1), int(match.group(2)), int(match.group(3) or 0)
    buildings = generate_suite(Request(kind, first), count)
    paths = [folder / f"{b.scenario.name}.yaml" for b in buildings]
    for path, building in zip(paths, buildings, strict=True):
        if path.exists() and path.read_text(encoding="utf-8", errors="replace") != building.text:
            raise BadInputError(f"{path}: differs from the building its seed gives; move it away to regenerate")
    folder.mkdir(parents=True, exist_ok=True)
    for path, building in zip(paths, buildings, strict=True):
        if not path.exists():
            write_text(path, building.text)
    return paths
