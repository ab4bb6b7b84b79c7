"""Options for the HTTP-backend tests (the loopback `server` fixture is in tests/conftest.py)."""

from __future__ import annotations

from typing import Any

import pytest


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
