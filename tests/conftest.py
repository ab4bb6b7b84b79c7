"""One scriptable loopback HTTP server for every test that talks HTTP (real sockets on 127.0.0.1, no mocks).

The server answers each request with the next scripted `Reply` (then with `default`, a Reply or a function
of the request) and records what it saw. A reply is either a plain answer (status, headers, JSON or raw
body, optionally late) or a fault:

- "ok"/"raw": the status and body (dict/list sent as JSON, str/bytes raw) with `content_type`;
- "hang": wait `delay_s` before answering; "slow": headers at once, then the body byte by byte, `delay_s`
  apart; "truncated": a Content-Length larger than the body sent, then close;
- "drop": close the connection without answering; "reset": a TCP RST, no answer.

Fixtures: `server` and `fault_server` (the same class: reply scripts and fault scripts), `closed_port_url`,
and `fault_kit` (what test modules need by name: they cannot import conftest under --import-mode=importlib);
`listening(pid)` gives the TCP addresses a process and its children listen on.
"""

from __future__ import annotations

import ipaddress
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

SMALL_ROOM = str(Path(__file__).parent / "runner" / "small_room.yaml")


@dataclass
class Reply:
    """One scripted answer (see the module docstring for the kinds)."""

    status: int = 200
    body: Any = None  # dict/list -> JSON; str/bytes -> raw
    headers: dict[str, str] = field(default_factory=dict)
    delay_s: float = 0.0  # [s] before answering ("ok", "hang"), or between body bytes ("slow")
    kind: str = "ok"
    content_type: str = "application/json"


def Fault(  # noqa: N802 - reads like the class it builds, as the fault tests have always written it
    kind: str = "ok",
    status: int = 200,
    body: Any = None,
    content_type: str = "application/json",
    headers: dict[str, str] | None = None,
    delay_s: float = 0.0,
) -> Reply:
    """A scripted fault: the kind first, as the fault tables read."""
    return Reply(status, body, dict(headers or {}), delay_s, kind, content_type)


@dataclass
class Seen:
    """One request as the server received it."""

    method: str
    path: str
    headers: dict[str, str]
    body: Any
    t: float  # [s] perf_counter at arrival


class LoopbackServer:
    """A ThreadingHTTPServer on 127.0.0.1 answering from a queue of replies (then `default`)."""

    def __init__(self) -> None:
        self.script: deque[Reply] = deque()
        self.default: Reply | Callable[[Seen], Reply] = Reply(500, {"error": "no reply scripted"})
        self.seen: list[Seen] = []
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
                headers = {k.lower(): v for k, v in self.headers.items()}
                seen = Seen(self.command, self.path, headers, body, time.perf_counter())
                with owner._lock:
                    owner.seen.append(seen)
                    reply = owner.script.popleft() if owner.script else owner.default
                if callable(reply):
                    reply = reply(seen)
                try:
                    owner._answer(self, reply)
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
    def reply(
        status: int = 200,
        body: Any = None,
        headers: dict[str, str] | None = None,
        delay_s: float = 0.0,
        drop: bool = False,
    ) -> Reply:
        """Build a scripted reply (`drop` closes the connection without answering)."""
        return Reply(status, body, dict(headers or {}), delay_s, "drop" if drop else "ok")

    def push(self, *replies: Reply) -> None:
        """Queue replies, answered in order."""
        self.script.extend(replies)

    @staticmethod
    def _payload(reply: Reply) -> bytes:
        if isinstance(reply.body, (dict, list)):
            return json.dumps(reply.body).encode()
        if isinstance(reply.body, str):
            return reply.body.encode()
        return reply.body or b""

    def _answer(self, handler: BaseHTTPRequestHandler, reply: Reply) -> None:
        if reply.kind in ("drop", "reset"):
            handler.close_connection = True
            if reply.kind == "reset":
                # SO_LINGER with a zero timeout turns close() into a TCP RST: "connection reset by peer"
                handler.connection.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
                handler.connection.close()
            else:
                handler.connection.shutdown(socket.SHUT_RDWR)
            return
        if reply.kind != "slow" and reply.delay_s:
            time.sleep(reply.delay_s)
        payload = self._payload(reply)
        handler.send_response(reply.status)
        handler.send_header("Content-Type", reply.content_type)
        declared = len(payload) * 2 + 10 if reply.kind == "truncated" else len(payload)
        handler.send_header("Content-Length", str(declared))
        for key, value in reply.headers.items():
            handler.send_header(key, value)
        handler.end_headers()
        if reply.kind == "slow":
            for i in range(len(payload)):
                handler.wfile.write(payload[i : i + 1])
                handler.wfile.flush()
                time.sleep(reply.delay_s)
            return
        handler.wfile.write(payload)
        if reply.kind == "truncated":
            handler.wfile.flush()
            handler.close_connection = True
            handler.connection.shutdown(socket.SHUT_RDWR)

    def close(self) -> None:
        """Stop serving and free the port."""
        self.httpd.shutdown()
        self.httpd.server_close()


@pytest.fixture
def server() -> Iterator[LoopbackServer]:
    """A loopback server scripted with replies (`server.reply(...)`, `server.push`, `server.default`)."""
    fake = LoopbackServer()
    assert fake.httpd.server_address[0] == "127.0.0.1"
    yield fake
    fake.close()


@pytest.fixture
def fault_server() -> Iterator[LoopbackServer]:
    """The same server, scripted with faults (`fault_kit["Fault"](kind, status, ...)`)."""
    fake = LoopbackServer()
    fake.default = Fault("ok", 500, {"error": "unscripted"})
    yield fake
    fake.close()


@pytest.fixture(scope="session")
def fault_kit() -> dict[str, Any]:
    """What fault tests build scripts with (test modules cannot import conftest)."""
    return {"Fault": Fault, "FaultServer": LoopbackServer, "small_room": SMALL_ROOM}


@pytest.fixture
def closed_port_url() -> str:
    """A loopback URL where nothing listens (connection refused)."""
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    port = sock.getsockname()[1]
    sock.close()
    return f"http://127.0.0.1:{port}"


# --- which addresses a process listens on (servers started by tests must stay on loopback) ---------

_LISTEN = "0A"  # TCP state LISTEN in /proc/net/tcp*


def _decode_address(hex_address: str) -> tuple[str, int]:
    """`0100007F:1F90` (IPv4) or 32 hex digits + port (IPv6), as the kernel prints them, → (ip, port)."""
    host, port = hex_address.split(":")
    raw = bytes.fromhex(host)
    # The kernel prints each 32-bit word in host (little-endian) order.
    swapped = b"".join(raw[i : i + 4][::-1] for i in range(0, len(raw), 4))
    return str(ipaddress.ip_address(swapped)), int(port, 16)


def _listening_by_inode() -> dict[int, tuple[str, int]]:
    found: dict[int, tuple[str, int]] = {}
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        try:
            lines = Path(table).read_text().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            fields = line.split()
            if fields[3] == _LISTEN:
                found[int(fields[9])] = _decode_address(fields[1])
    return found


def _children(pid: int) -> set[int]:
    kids: set[int] = set()
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            text = stat.read_text()
        except OSError:
            continue
        ppid = int(text.rsplit(")", 1)[1].split()[1])  # the name in parentheses may hold spaces
        if ppid == pid:
            kids.add(int(stat.parent.name))
    return kids


def process_tree(pid: int) -> set[int]:
    """`pid` and every process below it."""
    tree, todo = set(), [pid]
    while todo:
        current = todo.pop()
        if current not in tree:
            tree.add(current)
            todo.extend(_children(current))
    return tree


def listen_addresses(pids: set[int]) -> list[tuple[str, int]]:
    """Every (ip, port) on which one of `pids` holds a listening TCP socket (read from /proc)."""
    by_inode = _listening_by_inode()
    found: list[tuple[str, int]] = []
    for pid in pids:
        try:
            fds = list(Path(f"/proc/{pid}/fd").iterdir())
        except OSError:
            continue
        for fd in fds:
            try:
                target = os.readlink(fd)
            except OSError:
                continue
            if target.startswith("socket:["):
                inode = int(target[8:-1])
                if inode in by_inode:
                    found.append(by_inode[inode])
    return sorted(set(found))


@pytest.fixture
def listening() -> Callable[[int], list[tuple[str, int]]]:
    """`listening(pid)`: the TCP addresses that process and its descendants listen on (Linux /proc)."""
    if not Path("/proc/net/tcp").exists():
        pytest.skip("needs Linux /proc to see listening sockets")
    return lambda pid: listen_addresses(process_tree(pid))


# --- scenarios with ideal sensing (tests of behaviour that sensing errors would blur) ---------------


@pytest.fixture
def ideal_scenario(tmp_path: Path) -> Callable[[str], str]:
    """`ideal_scenario(name)`: a copy of a bundled scenario with a noise-free detector and exact odometry.

    For tests of a planner's logic; the sensing errors themselves are tested in tests/sim.
    """
    import yaml

    from llmnav.world.scenario import OdometryConfig, resolve_scenario_path

    def make(name: str) -> str:
        data = yaml.safe_load(resolve_scenario_path(name).read_text(encoding="utf-8"))
        sensors = dict(data.get("sensors") or {})
        sensors["detector"] = {}
        sensors["odometry"] = OdometryConfig.exact().model_dump()
        data["sensors"] = sensors
        path = tmp_path / f"{name}_ideal.yaml"
        path.write_text(yaml.safe_dump(data), encoding="utf-8")
        return str(path)

    return make


@pytest.fixture
def install_planner(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Callable[[str, str, str], None]:
    """`install_planner(name, module, source)`: a third-party planner registered for one test, as `pip install`
    would: `source` written as `module`.py beside a dist-info whose entry point names `module:<class>`.

    `name` is the entry point (`spin = spin_planner:SpinPlanner` is `install_planner("spin",
    "spin_planner:SpinPlanner", source)`).
    """
    site = tmp_path / "site-packages"

    def install(name: str, target: str, source: str) -> None:
        module = target.split(":", 1)[0]
        info = site / f"{module}-0.1.dist-info"
        info.mkdir(parents=True)
        (site / f"{module}.py").write_text(source, encoding="utf-8")
        (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {module}\nVersion: 0.1\n")
        (info / "entry_points.txt").write_text(f"[llmnav.planners]\n{name} = {target}\n")
        monkeypatch.syspath_prepend(str(site))

    return install
