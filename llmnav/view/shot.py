"""A PNG screenshot of a page, taken by a headless Chromium (the system's; nothing is downloaded).

Used by `llmnav view --screenshot` (the README's picture is made this way). The browser runs with a
fresh profile and no network features; `step` selects a decision through the page's `#step=K` address.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
from pathlib import Path

from llmnav.errors import BadInputError

BROWSER_ENV = "LLMNAV_CHROMIUM"  # path of the browser to use, when it is not /usr/bin/chromium
BROWSER_FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--hide-scrollbars",
)
TIMEOUT_S = 90.0  # [s] a cold start on a loaded machine takes a few seconds


def find_browser() -> str | None:
    """The Chromium to drive: $LLMNAV_CHROMIUM, /usr/bin/chromium, or chromium / google-chrome on PATH."""
    candidates = [os.environ.get(BROWSER_ENV), "/usr/bin/chromium"]
    candidates += [shutil.which(name) for name in ("chromium", "chromium-browser", "google-chrome")]
    for candidate in candidates:
        if candidate and Path(candidate).is_file() and os.access(candidate, os.X_OK):
            return candidate
    return None


def screenshot(page: Path, out: Path, *, step: int | None = None, width: int = 1400, height: int = 900) -> Path:
    """Write a PNG of `page` as a browser window of `width` × `height` pixels shows it."""
    browser = find_browser()
    if browser is None:
        raise BadInputError(f"--screenshot needs Chromium (apt-get install chromium, or set {BROWSER_ENV})")
    if out.suffix.lower() != ".png":
        raise BadInputError(f"--screenshot {out}: give a file ending in .png")
    url = page.resolve().as_uri() + (f"#step={step}" if step is not None else "")
    out = out.resolve()
    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="llmnav-chromium-") as profile:
        command = [
            browser,
            *BROWSER_FLAGS,
            f"--user-data-dir={profile}",
            f"--window-size={width},{height}",
            f"--screenshot={out}",
            url,
        ]
        try:
            result = subprocess.run(command, capture_output=True, text=True, timeout=TIMEOUT_S, check=False)
        except (OSError, subprocess.TimeoutExpired) as err:
            raise BadInputError(f"--screenshot: {browser} failed: {err}") from None
    if result.returncode != 0 or not out.is_file():
        last = (result.stderr.strip().splitlines() or ["no output"])[-1]
        raise BadInputError(f"--screenshot: {browser} wrote no picture (exit {result.returncode}): {last}")
    return out
