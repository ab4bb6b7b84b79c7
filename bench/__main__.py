"""`make bench`: run every benchmark module's `main()` in one process and print its table."""

from __future__ import annotations

import importlib
import sys

MODULES = [
    "bench.sim",
    "bench.guard",
    "bench.local",
    "bench.decision",
    "bench.ablate",
    "bench.calibrate",
    "bench.information",
    "bench.rl",
    # bench.protocol (the 200-episode sweep, ~15 min) runs only when named: `python -m bench protocol`.
]


def main() -> int:
    """Run the benchmarks named on the command line (default: all)."""
    names = [f"bench.{n}" for n in sys.argv[1:]] or MODULES
    for name in names:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as err:
            if err.name != name:
                raise
            print(f"[{name}] not present, skipped")
            continue
        module.main()
    return 0


if __name__ == "__main__":
    sys.exit(main())
