"""`make bench`: run benchmark modules' `main()` in one process and print their tables.

`python -m bench [--quick] [NAME ...]`: the named modules (default: all but `protocol`; with `--quick`,
all of them). `--quick` (or `LLMNAV_BENCH_QUICK=1`) runs each with a few iterations: a check that the
benchmarks still run, not a measurement. A module that raises is reported and the others still run; the
exit status is then 1.
"""

from __future__ import annotations

import importlib
import sys
import time
import traceback

from bench import quick_from_env

MODULES = [
    "sim",
    "guard",
    "local",
    "decision",
    "ablate",
    "calibrate",
    "information",
    "rl",
    "localize",
]
# Long sweeps run in full only when named: `python -m bench protocol` (200 factory episodes, several
# minutes), `python -m bench buildings` (100 generated flats x 3 tasks x 7 conditions, hours).
NAMED_ONLY = ["protocol", "buildings"]
USAGE = "usage: python -m bench [--quick] [NAME ...]   (names: " + ", ".join(MODULES + NAMED_ONLY) + ")"


def main(argv: list[str] | None = None) -> int:
    """Run the benchmarks named in `argv` (default: the command line); 1 if any raised, 2 on bad input."""
    args = sys.argv[1:] if argv is None else argv
    quick = quick_from_env() or "--quick" in args
    names = [a for a in args if a != "--quick"]
    if any(a in ("-h", "--help") for a in names):
        print(USAGE)
        return 0
    unknown = [n for n in names if n not in MODULES + NAMED_ONLY]
    if unknown:
        print(f"unknown benchmark(s) {', '.join(unknown)}; {USAGE}", file=sys.stderr)
        return 2
    failed: list[str] = []
    for name in names or (MODULES + NAMED_ONLY if quick else MODULES):
        started = time.perf_counter()
        try:
            module = importlib.import_module(f"bench.{name}")
            module.main(quick=quick)
        except Exception:  # a broken benchmark: say which and why, run the others, exit 1 at the end
            traceback.print_exc()
            failed.append(name)
            print(f"[bench.{name}] FAILED", file=sys.stderr)
        sys.stdout.flush()
        if quick:
            print(f"[bench.{name}] quick run took {time.perf_counter() - started:.1f} s", file=sys.stderr)
    if failed:
        print(f"benchmarks that failed: {', '.join(failed)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
