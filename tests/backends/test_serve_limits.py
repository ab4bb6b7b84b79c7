"""`llmnav serve` (the real executable, the bundled model, on 127.0.0.1 with a key) answers requests that
would have hung it on their headers alone: `Content-Length: abc` (it never answered), a 1 GB body without
the key (it read it whole first), a chunked body; a good request on the same server still works.
"""

from __future__ import annotations

import socket
import time

import httpx

ANSWER_WITHIN_S = 2.0


def _status_of(url: str, head: str) -> tuple[int | None, float]:
    """Send only a request's headers; (the HTTP status answered, seconds it took)."""
    host, port = url.removeprefix("http://").split("/")[0].split(":")
    started = time.monotonic()
    with socket.create_connection((host, int(port)), timeout=10) as sock:
        sock.sendall(head.encode())
        data = b""
        try:
            while b"\r\n" not in data and (chunk := sock.recv(4096)):
                data += chunk
        except TimeoutError:
            pass
    status = int(data.split(b" ", 2)[1]) if data.startswith(b"HTTP/") else None
    return status, time.monotonic() - started


def test_serve_answers_bad_requests_on_their_headers(serve_process) -> None:
    _process, url, key = serve_process
    path = "/v1/chat/completions"
    cases = {
        "no key, 1 GB body declared": (f"POST {path} HTTP/1.1\r\nHost: x\r\nContent-Length: {1 << 30}\r\n\r\n", 401),
        "key, Content-Length abc": (
            f"POST {path} HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer {key}\r\nContent-Length: abc\r\n\r\n",
            400,
        ),
        "key, 1 GB body declared": (
            f"POST {path} HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer {key}\r\nContent-Length: {1 << 30}\r\n\r\n",
            413,
        ),
        "key, chunked": (
            f"POST {path} HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer {key}\r\nTransfer-Encoding: chunked\r\n\r\n",
            411,
        ),
    }
    got = {name: _status_of(url.removesuffix("/v1"), head) for name, (head, _) in cases.items()}
    assert {name: status for name, (status, _) in got.items()} == {name: want for name, (_, want) in cases.items()}
    assert all(elapsed < ANSWER_WITHIN_S for _, elapsed in got.values()), got
    reply = httpx.post(
        f"{url}/chat/completions",
        json={"model": "local", "max_tokens": 2, "messages": [{"role": "user", "content": "Hi"}]},
        headers={"Authorization": f"Bearer {key}"},
        timeout=120,
    )
    assert reply.status_code == 200 and reply.json()["choices"], reply.text
