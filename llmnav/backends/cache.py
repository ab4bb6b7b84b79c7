"""A reply cache for the HTTP backends (`--cache DIR`): a re-run of the same requests does not pay twice.

One file per request, `DIR/<2 hex>/<sha256>.json`, named by the SHA-256 of what decides the answer: the
backend's name, its server (base URL with any credentials removed), the path, the whole JSON body (model,
messages with their images, sampling settings, seed, answer schema) and `CACHE_FORMAT`. Headers, where the
API keys travel, are no part of the key and are never stored.

- Written atomically (a temporary file, then a rename): a reader sees a whole entry or none.
- A torn, corrupt or foreign entry, or one of another `CACHE_FORMAT`, is a miss: the request goes to the
  server and a good entry replaces it. Never a crash, never a wrong answer.
- An entry whose text would contain one of the backend's secrets (in any of the forms the run log
  redacts) is not written.
- Only successful replies are stored; errors always reach the server again.

A hit returns the stored reply with the latency the original request took, so tables of model time keep
the model's time; the run log marks the call `"cache": "hit"`, and `llmnav score` labels the run.
"""

from __future__ import annotations

import hashlib
import json
import logging
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from llmnav.core.safefiles import UnsafeFileError, read_bytes, write_bytes
from llmnav.core.safefiles import loads as bounded_loads
from llmnav.errors import BadInputError, expand_secrets, redact_userinfo

log = logging.getLogger(__name__)

# Bump when the entry layout or the meaning of a key changes: entries of another format are misses.
CACHE_FORMAT = 1
ENTRY_LIMIT = 64 << 20  # [bytes] one entry (a reply is at most what the HTTP client accepts)
CacheState = Literal["hit", "miss", "off"]


@dataclass(frozen=True)
class CachedReply:
    """A stored reply: the server's JSON and the wall time [s] the original request took."""

    data: dict[str, Any]
    elapsed_s: float


class ReplyCache:
    """The reply cache in one folder (created if missing); safe to share between threads and processes."""

    def __init__(self, root: Path | str) -> None:
        self.root = Path(root)
        try:
            self.root.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise BadInputError(f"--cache {self.root}: cannot create the folder ({err.strerror or err})") from None
        if not self.root.is_dir():
            raise BadInputError(f"--cache {self.root}: not a folder")

    def __repr__(self) -> str:
        return f"<ReplyCache {self.root}>"

    @staticmethod
    def key(backend: str, base_url: str, path: str, body: dict[str, Any]) -> str:
        """The entry name of one request (credentials in the URL are removed before hashing)."""
        identity = {
            "format": CACHE_FORMAT,
            "backend": backend,
            "server": redact_userinfo(base_url),
            "path": path,
            "body": body,
        }
        text = json.dumps(identity, sort_keys=True, separators=(",", ":"), ensure_ascii=False)
        return hashlib.sha256(text.encode("utf-8", "surrogateescape")).hexdigest()

    def path(self, key: str) -> Path:
        """Where the entry `key` lives."""
        return self.root / key[:2] / f"{key}.json"

    def get(self, key: str) -> CachedReply | None:
        """The stored reply for `key`, or None (absent, torn, corrupt, another format: all misses)."""
        try:
            entry = bounded_loads(read_bytes(self.path(key), limit=ENTRY_LIMIT, root=self.root))
        except FileNotFoundError:
            return None
        except (OSError, UnsafeFileError, ValueError, UnicodeDecodeError) as err:
            log.info("cache entry %s unreadable (%s): a miss", key[:12], err)
            return None
        if not isinstance(entry, dict) or entry.get("format") != CACHE_FORMAT or entry.get("key") != key:
            return None
        data, elapsed = entry.get("reply"), entry.get("elapsed_s")
        if not isinstance(data, dict) or not isinstance(elapsed, (int, float)) or isinstance(elapsed, bool):
            return None
        return CachedReply(data, max(0.0, float(elapsed)))

    def put(self, key: str, data: dict[str, Any], elapsed_s: float, secrets: Iterable[str] = ()) -> bool:
        """Store a reply atomically; False (and nothing written) when it holds a secret or cannot be written."""
        entry = {"format": CACHE_FORMAT, "key": key, "elapsed_s": round(elapsed_s, 4), "reply": data}
        text = json.dumps(entry, ensure_ascii=False)
        if any(form in text for form in expand_secrets(secrets)):
            log.warning("cache: a reply that contains the backend's key is not stored")
            return False
        target = self.path(key)
        try:
            target.parent.mkdir(exist_ok=True)
            write_bytes(target, text.encode("utf-8", "surrogateescape"))
        except OSError as err:  # a full disk loses the entry, not the run
            log.warning("cache: entry not written (%s)", err)
            return False
        return True
