"""Serve bounds: the front of `llmnav serve` (`llmnav.serve.front.Front`) on real sockets on 127.0.0.1, relaying
to a loopback stand-in for llama.cpp's server. A client that never finishes its headers, trickles its body,
idles, declares a huge or malformed length, sends chunks, or sends a body without the key is answered or
cut within the stated limits, without the body being read and without reaching llama.cpp.

Each case reproduces one of the third hostile pass: `Content-Length: abc` logged a ValueError and never
answered; an unauthenticated 1 GB body was read whole before the key was checked; 500 connections that
never finished their headers held 513 threads for good. Counted as category "serve bounds".
"""

from __future__ import annotations

import json
import socket
import time
from collections.abc import Iterator
from typing import Any

import pytest

from llmnav.serve.front import Front, Limits

CATEGORY = "serve bounds"
KEY = "serve-bounds-key-5d1e"
LIMITS = Limits(max_body_bytes=4096, header_s=0.6, body_s=0.8, idle_s=0.7, max_connections=8)
SLACK_S = 1.5  # [s] scheduling on a loaded 2-core machine


@pytest.fixture
def front(server: Any) -> Iterator[Front]:
    """A front with a key and small limits, relaying to the loopback `server` (answers 200 `{"ok": true}`)."""
    server.default = server.reply(200, {"ok": True})
    upstream = int(server.url.rsplit(":", 1)[1])
    relay = Front("127.0.0.1", 0, upstream, api_key=KEY, limits=LIMITS)
    relay.start()
    yield relay
    relay.stop()


def connect(front: Front) -> socket.socket:
    sock = socket.create_connection(("127.0.0.1", front.port), timeout=10)
    sock.settimeout(10)
    return sock


def read_reply(sock: socket.socket) -> tuple[int | None, float]:
    """(HTTP status or None when the server closed without answering, seconds until then)."""
    started = time.monotonic()
    data = b""
    try:
        while b"\r\n" not in data:
            chunk = sock.recv(4096)
            if not chunk:
                break
            data += chunk
    except (TimeoutError, ConnectionResetError):
        pass
    elapsed = time.monotonic() - started
    return (int(data.split(b" ", 2)[1]) if data.startswith(b"HTTP/") else None), elapsed


def read_whole_reply(sock: socket.socket) -> tuple[int, bytes]:
    """One complete response with a Content-Length: (status, body)."""
    data = b""
    while b"\r\n\r\n" not in data:
        chunk = sock.recv(4096)
        assert chunk, f"closed mid-reply: {data!r}"
        data += chunk
    head, _, body = data.partition(b"\r\n\r\n")
    lines = head.split(b"\r\n")
    length = int(next(line.split(b":", 1)[1] for line in lines if line.lower().startswith(b"content-length")))
    while len(body) < length:
        chunk = sock.recv(4096)
        assert chunk, "closed mid-body"
        body += chunk
    return int(head.split(b" ", 2)[1]), body


def closed_within(sock: socket.socket, seconds: float) -> bool:
    """Whether the server closes the connection within `seconds` (reading whatever it sends)."""
    sock.settimeout(seconds)
    deadline = time.monotonic() + seconds
    try:
        while time.monotonic() < deadline:
            if not sock.recv(4096):
                return True
    except ConnectionResetError:
        return True
    except TimeoutError:
        return False
    return False


def post(length: str | None, *, key: str | None = KEY, extra: str = "", body: bytes = b"") -> bytes:
    head = "POST /v1/chat/completions HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
    if length is not None:
        head += f"Content-Length: {length}\r\n"
    if key is not None:
        head += f"Authorization: Bearer {key}\r\n"
    return (head + extra + "\r\n").encode() + body


@pytest.mark.parametrize(
    ("name", "request_bytes", "status"),
    [
        ("no key, 1 GB declared", post(str(1 << 30), key=None), 401),
        ("wrong key, 1 GB declared", post(str(1 << 30), key="guess"), 401),
        ("key, 1 GB declared", post(str(1 << 30)), 413),
        ("length abc", post("abc"), 400),
        ("length -5", post("-5"), 400),
        ("two lengths", post("5", extra="Content-Length: 6\r\n"), 400),
        ("length 1e3", post("1e3"), 400),
        ("chunked", post(None, extra="Transfer-Encoding: chunked\r\n", body=b"5\r\nhello\r\n0\r\n\r\n"), 411),
        ("chunked, no key", post(None, key=None, extra="Transfer-Encoding: chunked\r\n"), 401),
    ],
)
def test_a_bad_request_is_answered_on_its_headers(
    name: str, request_bytes: bytes, status: int, front: Front, server: Any, tally: Any
) -> None:
    tally.add(CATEGORY, tried=1)
    with connect(front) as sock:
        sock.sendall(request_bytes)  # no body follows: an answer needs nothing more than the headers
        got, elapsed = read_reply(sock)
        ok = got == status and elapsed < SLACK_S and closed_within(sock, SLACK_S)
    tally.add(CATEGORY, failures=int(not ok))
    assert (got, elapsed < SLACK_S) == (status, True), f"{name}: {got} after {elapsed:.1f} s"
    assert not server.seen, "the request reached llama.cpp"


def test_a_good_request_is_relayed_and_the_connection_kept(front: Front, server: Any, tally: Any) -> None:
    tally.add(CATEGORY, tried=1)
    body = json.dumps({"messages": []}).encode()
    with connect(front) as sock:
        for _ in range(2):  # keep-alive: the second request on the same connection
            sock.sendall(post(str(len(body)), body=body))
            status, answer = read_whole_reply(sock)
            assert (status, json.loads(answer)) == (200, {"ok": True})
    assert [s.body for s in server.seen] == [{"messages": []}] * 2


@pytest.mark.parametrize("phase", ["headers never end", "headers drip", "body drips", "idle keep-alive"])
def test_a_slow_or_idle_client_is_cut_within_its_limit(phase: str, front: Front, server: Any, tally: Any) -> None:
    tally.add(CATEGORY, tried=1)
    limit = {"headers never end": LIMITS.header_s, "headers drip": LIMITS.header_s, "body drips": LIMITS.body_s,
             "idle keep-alive": LIMITS.idle_s}[phase]  # fmt: skip
    with connect(front) as sock:
        started = time.monotonic()
        if phase == "headers never end":
            sock.sendall(b"POST /v1/chat/completions HTTP/1.1\r\nHost: x\r\n")
        elif phase == "headers drip":  # a byte every 0.2 s: each read is quick, the headers never end
            for byte in b"POST /v1/chat/completions HTTP/1.1\r\nHost: x\r\nX-Slow: " + b"a" * 40:
                try:
                    sock.send(bytes([byte]))
                except OSError:
                    break
                time.sleep(0.2)
                if time.monotonic() - started > limit + SLACK_S:
                    break
        elif phase == "body drips":
            sock.sendall(post("100"))
            for _ in range(40):
                try:
                    sock.send(b"x")
                except OSError:
                    break
                time.sleep(0.1)
                if time.monotonic() - started > limit + SLACK_S:
                    break
        else:
            sock.sendall(post("2", body=b"{}"))
            assert read_reply(sock)[0] == 200
            started = time.monotonic()
        cut = closed_within(sock, limit + SLACK_S - (time.monotonic() - started))
        elapsed = time.monotonic() - started
    tally.add(CATEGORY, failures=int(not cut))
    assert cut, f"{phase}: still open after {elapsed:.1f} s (limit {limit} s)"
    assert elapsed >= limit * 0.8 or phase == "body drips" and elapsed >= LIMITS.body_s * 0.8


def test_connections_over_the_cap_are_closed_and_the_threads_freed(front: Front, tally: Any) -> None:
    tally.add(CATEGORY, tried=1)
    held = [connect(front) for _ in range(LIMITS.max_connections)]
    try:
        for sock in held:
            sock.sendall(b"POST / HTTP/1.1\r\n")  # never finished
        time.sleep(0.2)
        extra = connect(front)
        refused = closed_within(extra, 1.0)
        extra.close()
        assert refused, "a connection over the cap was kept"
        assert all(closed_within(sock, LIMITS.header_s + SLACK_S) for sock in held)
        time.sleep(0.2)
        with connect(front) as sock:  # room again: a good request goes through
            sock.sendall(post("2", body=b"{}"))
            assert read_reply(sock)[0] == 200
    finally:
        for sock in held:
            sock.close()
