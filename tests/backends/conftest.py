"""Options for the HTTP-backend tests (the loopback `server` fixture is in tests/conftest.py)."""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

LLMNAV = str(Path(sys.executable).parent / "llmnav")
SERVE_KEY = "serve-client-key-81c3"


@pytest.fixture
def sleeps() -> list[float]:
    """Collects the waits a client asks for, without waiting (pass `sleep=sleeps.append`)."""
    return []


@pytest.fixture
def fast() -> dict[str, Any]:
    """HTTP options that keep retries and timeouts in the milliseconds."""
    return {
        "max_retries": 2,
        "backoff_base_s": 0.01,
        "backoff_max_s": 0.05,
        "timeout_s": 2.0,
        "connect_timeout_s": 1.0,
    }


def start_serve(*args: str) -> tuple[subprocess.Popen[str], str, str]:
    """Start `llmnav serve --port 0 ARGS` (the bundled model, on 127.0.0.1, with a key): (process, base URL, key)."""
    process = subprocess.Popen(
        [LLMNAV, "serve", "--port", "0", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "LLMNAV_API_KEY": SERVE_KEY},
    )
    assert process.stdout is not None
    url = process.stdout.readline().strip()
    process.stdout.readline()
    if not url.startswith("http://127.0.0.1:"):
        process.kill()
        raise AssertionError(f"llmnav serve did not start: {url!r} {process.communicate(timeout=30)[1][-2000:]}")
    return process, url, SERVE_KEY


def end_serve(process: subprocess.Popen[str]) -> None:
    """Kill a server the test did not stop itself."""
    if process.poll() is None:
        process.kill()
        process.wait(timeout=30)


@pytest.fixture
def serve_process() -> Iterator[tuple[subprocess.Popen[str], str, str]]:
    """`llmnav serve --port 0` (the bundled model, on 127.0.0.1, with a key): (process, base URL, key).

    Killed at the end if the test did not stop it.
    """
    process, url, key = start_serve()
    try:
        yield process, url, key
    finally:
        end_serve(process)
