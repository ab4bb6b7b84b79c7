"""Servers: `backends --check` against servers that never answer or drip, the Gemini check against a
loopback fake of the API's model list, and `serve --host` messages that are true.

Each case reproduces one of an earlier llmnav: a check taking 112 s (253 s against a drip), Gemini's check
that could not work (no model-list path), and `--host` values that warned wrongly, printed an unusable
URL, or served with no key off loopback. Counted as category "servers".
"""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Iterator
from typing import Any

import pytest
from typer.testing import CliRunner

from llmnav.cli import app
from llmnav.errors import BadInputError
from llmnav.serve import check_host

CATEGORY = "servers"
GEMINI_KEY = "AIzaFAKE-gemini-check-0123456789"


@pytest.fixture
def silent_port() -> Iterator[int]:
    """A loopback port that accepts connections (the kernel's backlog) and never answers."""
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    sock.listen(16)
    yield sock.getsockname()[1]
    sock.close()


@pytest.fixture
def drip_port() -> Iterator[int]:
    """A loopback server that answers every request one byte a second, without end."""
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    sock.listen(16)
    stop = threading.Event()

    def drip(conn: socket.socket) -> None:
        with conn:
            try:
                conn.recv(65536)
                conn.sendall(b"HTTP/1.1 200 OK\r\nContent-Type: application/json\r\nContent-Length: 100000\r\n\r\n")
                while not stop.wait(1.0):
                    conn.sendall(b" ")
            except OSError:
                pass

    def serve() -> None:
        while not stop.is_set():
            try:
                conn, _ = sock.accept()
            except OSError:
                return
            threading.Thread(target=drip, args=(conn,), daemon=True).start()

    threading.Thread(target=serve, daemon=True).start()
    yield sock.getsockname()[1]
    stop.set()
    sock.close()


@pytest.mark.parametrize("kind", ["silent", "drip"])
def test_check_of_a_dead_server_answers_within_ten_seconds(kind: str, silent_port: int, drip_port: int,
                                                           tally: Any, monkeypatch: Any) -> None:  # fmt: skip
    tally.add(CATEGORY, tried=1)
    monkeypatch.delenv("OPENAI_API_KEY", raising=False)
    port = silent_port if kind == "silent" else drip_port
    t0 = time.perf_counter()
    result = CliRunner().invoke(app, ["backends", "--check", f"openai:m@http://127.0.0.1:{port}/v1"])
    elapsed = time.perf_counter() - t0
    tally.note(CATEGORY, f"check of a {kind} server [s]", round(elapsed, 1))
    assert result.exit_code == 1 and "reachable" in result.output and "timeout" in result.output, result.output
    assert elapsed < 12, f"{elapsed:.1f} s"


def test_gemini_check_uses_the_model_list(server: Any, tally: Any, monkeypatch: Any) -> None:
    tally.add(CATEGORY, tried=2)
    monkeypatch.setenv("GEMINI_API_KEY", GEMINI_KEY)
    monkeypatch.setenv("LLMNAV_GEMINI_BASE_URL", server.url)
    listed = {"models": [{"name": "models/gemini-2.0-flash"}, {"name": "models/gemini-1.5-pro"}]}

    def reply(seen: Any) -> Any:
        if seen.method == "GET" and seen.path.startswith("/v1beta/models"):
            return server.reply(200, listed)
        if seen.path.endswith(":generateContent"):
            text = '{"colour": "blue"}'
            return server.reply(200, {"candidates": [{"content": {"parts": [{"text": text}]}}]})
        return server.reply(404, "<html>not found</html>")

    server.default = reply
    result = CliRunner().invoke(app, ["backends", "--check", "gemini:gemini-2.0-flash"])
    assert result.exit_code == 0, result.output
    assert "models listed: 2: gemini-2.0-flash, gemini-1.5-pro" in result.output
    assert "model present: gemini-2.0-flash is listed" in result.output
    gets = [s for s in server.seen if s.method == "GET"]
    assert gets and gets[0].path.startswith("/v1beta/models") and gets[0].headers["x-goog-api-key"] == GEMINI_KEY
    absent = CliRunner().invoke(app, ["backends", "--check", "gemini:gemini-9"])
    assert absent.exit_code == 1 and "gemini-9 is not listed" in absent.output, absent.output


def test_serve_host_messages_are_true(tally: Any, monkeypatch: Any) -> None:
    tally.add(CATEGORY, tried=5)
    assert check_host("localhost", None) == "127.0.0.1"  # loopback: no key needed, no warning
    assert check_host("::1", None) == "::1"
    assert check_host("0.0.0.0", "k3y") == "0.0.0.0"
    with pytest.raises(BadInputError, match="give an address"):
        check_host("", None)
    with pytest.raises(BadInputError, match="reachable from other machines; give a key"):
        check_host("0.0.0.0", None)
    monkeypatch.delenv("LLMNAV_API_KEY", raising=False)
    for args in (["--host", ""], ["--host", "0.0.0.0"], ["--alias", ""]):
        result = CliRunner().invoke(app, ["serve", *args, "--port", "0"])
        assert result.exit_code == 2 and "Traceback" not in result.output, (args, result.output)
        assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)


@pytest.mark.parametrize("kind", ["silent", "drip", "refused"])
def test_retries_share_one_deadline(kind: str, silent_port: int, drip_port: int, closed_port_url: str,
                                    tally: Any) -> None:  # fmt: skip
    """Five tries of 90 s each at a dead server took 930 s: now every attempt and wait fits one deadline."""
    from llmnav.backends.http import DEADLINE_S, HttpOptions, JsonHttpClient
    from llmnav.errors import ModelError

    tally.add(CATEGORY, tried=1)
    assert HttpOptions().deadline_s is None and DEADLINE_S <= 60  # the default: 60 s a request, all included
    url = {"silent": f"http://127.0.0.1:{silent_port}", "drip": f"http://127.0.0.1:{drip_port}",
           "refused": closed_port_url}[kind]  # fmt: skip
    options = HttpOptions(timeout_s=1.5, connect_timeout_s=1.0, max_retries=20, backoff_base_s=0.3, deadline_s=3.0)
    client = JsonHttpClient("test", url, options)
    t0 = time.perf_counter()
    with pytest.raises(ModelError) as caught:
        client.post("/v1/chat/completions", {"messages": []})
    elapsed = time.perf_counter() - t0
    client.close()
    tally.note(CATEGORY, f"a {kind} server with a 3 s deadline [s]", round(elapsed, 1))
    assert elapsed < 3.0 + 1.0, f"{elapsed:.1f} s: {caught.value}"
    assert "attempt" in str(caught.value) and "\n" not in str(caught.value)


def test_the_deadline_defaults_to_sixty_seconds_and_a_longer_timeout(monkeypatch: Any, silent_port: int) -> None:
    """Without `deadline_s`, a request gets DEADLINE_S (or a longer `timeout_s` the user set, not a backend's
    default of 90 s): measured with the constant made small, against a server that never answers."""
    import llmnav.backends.http as http
    from llmnav.backends.openai import OpenAIOptions
    from llmnav.errors import ModelError

    monkeypatch.setattr(http, "DEADLINE_S", 2.0)
    cases = [(http.HttpOptions(timeout_s=1.0, max_retries=20, backoff_base_s=0.1), 2.0),
             (http.HttpOptions(timeout_s=3.0, max_retries=20, backoff_base_s=0.1), 3.0),
             (OpenAIOptions(max_retries=20, backoff_base_s=0.1), 2.0)]  # fmt: skip
    assert OpenAIOptions().timeout_s > 60  # its own default: one long answer, not a long wait for a dead server
    for options, expected in cases:
        timeout_s = options.timeout_s
        client = http.JsonHttpClient("test", f"http://127.0.0.1:{silent_port}", options)
        t0 = time.perf_counter()
        with pytest.raises(ModelError):
            client.post("/x", {})
        elapsed = time.perf_counter() - t0
        client.close()
        assert expected - 0.5 < elapsed < expected + 1.0, (timeout_s, elapsed)
