"""Shared pieces of the reliability suite: the counters behind `make reliability`'s table, a loopback
server that fails in every way an HTTP model server can, and small helpers.

Counters: every test adds what it tried and what went wrong to the session-wide `tally` (category →
tried, failures, unsafe motions, logs lost, leaked keys). At the end of the session they are written as
JSON (to `$LLMNAV_RELIABILITY_JSON`, default `.pytest_cache/reliability.json`) and, when the session ran
any test marked `reliability` (the full run), printed as a table (tests/reliability/report.py).
Failed tests are counted per category too, so a red test always shows in the table.
"""

from __future__ import annotations

import json
import os
import socket
import struct
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

import pytest

HERE = Path(__file__).parent
SMALL_ROOM = str(HERE.parent / "runner" / "small_room.yaml")
COUNTER_FIELDS = ("tried", "failures", "unsafe", "lost", "leaked", "crashes")
JSON_ENV = "LLMNAV_RELIABILITY_JSON"

# test module stem → table category
CATEGORIES = {
    "test_fuzz": "guard fuzzing",
    "test_backend_faults": "backend faults",
    "test_crash": "crash safety",
    "test_bad_input": "bad input",
    "test_secrets": "secrets",
    "test_fsm_deadline": "fsm deadline",
    "test_data_safety": "data safety",
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


# --- a loopback server that fails on purpose ------------------------------------------------------


@dataclass
class Fault:
    """One scripted answer of the fault server.

    kind: "ok" (status + JSON body), "raw" (status + raw body + content type), "hang" (sleep before
    answering), "slow" (headers at once, body trickled byte by byte), "reset" (TCP RST, no answer),
    "truncated" (Content-Length larger than the body sent, then close).
    """

    kind: str = "ok"
    status: int = 200
    body: Any = None
    content_type: str = "application/json"
    headers: dict[str, str] = field(default_factory=dict)
    delay_s: float = 0.0  # [s] hang: before answering; slow: between body bytes


@dataclass
class SeenRequest:
    path: str
    headers: dict[str, str]
    body: Any
    t: float  # [s] perf_counter at arrival


class FaultServer:
    """A ThreadingHTTPServer on 127.0.0.1 answering from a queue of Faults (then `default`)."""

    def __init__(self) -> None:
        self.script: deque[Fault] = deque()
        self.default: Fault | Callable[[SeenRequest], Fault] = Fault("ok", 500, {"error": "unscripted"})
        self.seen: list[SeenRequest] = []
        self._lock = threading.Lock()
        owner = self

        class Handler(BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"

            def _handle(self) -> None:
                length = int(self.headers.get("Content-Length") or 0)
                raw = self.rfile.read(length) if length else b""
                try:
                    body = json.loads(raw) if raw else None
                except ValueError:
                    body = raw
                seen = SeenRequest(
                    self.path, {k.lower(): v for k, v in self.headers.items()}, body, time.perf_counter()
                )
                with owner._lock:
                    owner.seen.append(seen)
                    fault = owner.script.popleft() if owner.script else owner.default
                if callable(fault):
                    fault = fault(seen)
                try:
                    owner._answer(self, fault)
                except (BrokenPipeError, ConnectionResetError, OSError):
                    self.close_connection = True  # the client gave up (timeouts)

            do_GET = _handle
            do_POST = _handle

            def log_message(self, format: str, *args: Any) -> None:  # noqa: A002
                pass

        self.httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.httpd.daemon_threads = True
        self.url = f"http://127.0.0.1:{self.httpd.server_address[1]}"
        self.thread = threading.Thread(target=self.httpd.serve_forever, kwargs={"poll_interval": 0.05})
        self.thread.daemon = True
        self.thread.start()

    @staticmethod
    def _payload(fault: Fault) -> bytes:
        if isinstance(fault.body, (dict, list)):
            return json.dumps(fault.body).encode()
        if isinstance(fault.body, str):
            return fault.body.encode()
        return fault.body or b""

    def _answer(self, handler: BaseHTTPRequestHandler, fault: Fault) -> None:
        payload = self._payload(fault)
        if fault.kind == "reset":
            handler.close_connection = True
            # SO_LINGER with a zero timeout turns close() into a TCP RST: "connection reset by peer"
            handler.connection.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
            handler.connection.close()
            return
        if fault.kind == "hang":
            time.sleep(fault.delay_s)
        handler.send_response(fault.status)
        handler.send_header("Content-Type", fault.content_type)
        declared = len(payload) * 2 + 10 if fault.kind == "truncated" else len(payload)
        handler.send_header("Content-Length", str(declared))
        for key, value in fault.headers.items():
            handler.send_header(key, value)
        handler.end_headers()
        if fault.kind == "slow":
            for i in range(len(payload)):
                handler.wfile.write(payload[i : i + 1])
                handler.wfile.flush()
                time.sleep(fault.delay_s)
            return
        handler.wfile.write(payload)
        if fault.kind == "truncated":
            handler.wfile.flush()
            handler.close_connection = True
            handler.connection.shutdown(socket.SHUT_RDWR)

    def push(self, *faults: Fault) -> None:
        self.script.extend(faults)

    def close(self) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()


@pytest.fixture
def fault_server() -> Iterator[FaultServer]:
    server = FaultServer()
    yield server
    server.close()


@pytest.fixture(scope="session")
def fault_kit() -> dict[str, Any]:
    """The classes tests need (test modules cannot import conftest under --import-mode=importlib)."""
    return {"Fault": Fault, "FaultServer": FaultServer, "small_room": SMALL_ROOM}
