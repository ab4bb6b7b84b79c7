"""Shared pieces of the reliability suite: the counters behind `make reliability`'s table (the loopback
server that fails in every way an HTTP model server can is `fault_server`, in tests/conftest.py).

Counters: every test adds what it tried and what went wrong to the session-wide `tally` (category →
tried, failures, unsafe motions, logs lost, leaked keys). At the end of the session they are written as
JSON (to `$LLMNAV_RELIABILITY_JSON`, default `.pytest_cache/reliability.json`) and, when the session ran
any test marked `reliability` (the full run), printed as a table (tests/reliability/report.py).
Failed tests are counted per category too, so a red test always shows in the table.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import pytest

HERE = Path(__file__).parent
COUNTER_FIELDS = ("tried", "failures", "unsafe", "lost", "leaked", "crashes")
JSON_ENV = "LLMNAV_RELIABILITY_JSON"

# test module stem → table category
CATEGORIES = {
    "test_fuzz": "fuzz: stepwise",
    "test_fuzz_planners": "fuzz: other planners",
    "test_backend_faults": "backend faults",
    "test_crash": "crash safety",
    "test_bad_input": "bad input",
    "test_secrets": "secrets",
    "test_fsm_deadline": "fsm deadline",
    "test_data_safety": "data safety",
    "test_hostile_folders": "hostile folders",
    "test_hostile_sizes": "hostile sizes",
    "test_servers": "servers",
    "test_stress": "stress: collisions",
    "test_hostile_replies": "hostile replies",
    "test_serve_bounds": "serve bounds",
    "test_hostile_plugins": "hostile plugins",
    "test_honest_accounting": "honest accounting",
    "test_scripts": "scoring scripts",
    "test_raw_access": "raw access",
    "test_crashed_runs": "crashed runs",
    "test_mode_fallback": "mode fallback",
    "test_dead_assist": "dead assist",
    "test_worker_kill": "worker kill",
}


class Tally:
    """Session-wide counters per category, plus free-form notes (fault kinds seen, latency figures)."""

    def __init__(self) -> None:
        self.counts: dict[str, dict[str, int]] = {}
        self.notes: dict[str, dict[str, Any]] = {}
        self.failed_tests: dict[str, int] = {}
        self.full = False

    def add(self, category: str, **counts: int) -> None:
        row = self.counts.setdefault(category, dict.fromkeys(COUNTER_FIELDS, 0))
        for key, value in counts.items():
            if key not in COUNTER_FIELDS:
                raise KeyError(key)
            row[key] += int(value)

    def note(self, category: str, key: str, value: Any) -> None:
        self.notes.setdefault(category, {})[key] = value

    def note_add(self, category: str, key: str, item: str) -> None:
        items = self.notes.setdefault(category, {}).setdefault(key, [])
        if item not in items:
            items.append(item)

    def to_json(self) -> dict[str, Any]:
        return {
            "full": self.full,
            "counts": self.counts,
            "failed_tests": self.failed_tests,
            "notes": self.notes,
        }


_TALLY = Tally()


@pytest.fixture(scope="session")
def tally() -> Tally:
    return _TALLY


def pytest_runtest_setup(item: pytest.Item) -> None:
    if item.get_closest_marker("reliability") is not None:
        _TALLY.full = True  # a test of the full run is running


def pytest_runtest_logreport(report: pytest.TestReport) -> None:
    if report.failed and "tests/reliability/" in report.nodeid.replace("\\", "/"):
        stem = Path(report.nodeid.split("::")[0]).stem
        category = CATEGORIES.get(stem, stem)
        _TALLY.failed_tests[category] = _TALLY.failed_tests.get(category, 0) + 1
        _TALLY.add(category, failures=1)


def pytest_terminal_summary(terminalreporter: Any, exitstatus: int, config: pytest.Config) -> None:
    if not _TALLY.counts and not _TALLY.failed_tests:
        return
    target = Path(os.environ.get(JSON_ENV) or (config.rootpath / ".pytest_cache" / "reliability.json"))
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_text(json.dumps(_TALLY.to_json(), indent=2) + "\n")
    except OSError:
        pass
    if _TALLY.full or os.environ.get(JSON_ENV):
        import importlib.util

        spec = importlib.util.spec_from_file_location("llmnav_reliability_report", HERE / "report.py")
        assert spec is not None and spec.loader is not None
        report = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(report)
        terminalreporter.write_line("")
        for line in report.render(_TALLY.to_json()).splitlines():
            terminalreporter.write_line(line)
