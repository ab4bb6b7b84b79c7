"""A bounded memo of continuation scores, so a deterministic model scores each (prefix, text) pair once.

A scored decision asks many questions whose answers it has already had: the content-free half of every
PMI ("Task: N/A") is the same for every task, each landmark's room is asked against the same twelve
room words in every episode, and the same landmark names, relational places and frontier
descriptions return decision after decision. A model at temperature 0 gives the same log-probability
for the same token sequence, so those answers are looked up instead of computed again.

The memo sits below the backend's `score`: planners, run logs and replay see every request as before
(a strict replay compares requests, not how the backend answered them), and the reply's meta says how
many continuations came from the memo (`memo_hits`). Keys are the exact prefix and continuation
strings; the places a request carries are ignored, since a model never reads them.

Scores then also stop depending on the prompt cache's state: llama.cpp may batch a cold prompt's
arithmetic differently from a cached one and differ in the last digits, and a memoised pair keeps the
value it was first given for the rest of the process.
"""

from __future__ import annotations

import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from typing import Any

from llmnav.core.chat import ContinuationScore, ScoreRequest, ScoreResult

# [entries] about 200 bytes each with their strings: 20 MB at most, thousands of episodes of menus
MEMO_ENTRIES = 100_000


class ScoreMemo:
    """Least-recently-used (prefix, continuation) -> score, thread-safe, at most `entries` pairs."""

    def __init__(self, entries: int = MEMO_ENTRIES) -> None:
        self.entries = entries
        self._scores: OrderedDict[tuple[str, str], ContinuationScore] = OrderedDict()
        self._lock = threading.Lock()

    def __len__(self) -> int:
        return len(self._scores)

    def get(self, prefix: str, text: str) -> ContinuationScore | None:
        """The remembered score of `text` after `prefix`, if any (and mark it recently used)."""
        with self._lock:
            found = self._scores.get((prefix, text))
            if found is not None:
                self._scores.move_to_end((prefix, text))
            return found

    def put(self, prefix: str, text: str, score: ContinuationScore) -> None:
        """Remember a score, forgetting the least recently used pair beyond the bound."""
        with self._lock:
            self._scores[(prefix, text)] = score
            self._scores.move_to_end((prefix, text))
            while len(self._scores) > self.entries:
                self._scores.popitem(last=False)


def memoised_score(
    memo: ScoreMemo, request: ScoreRequest, score: Callable[[ScoreRequest], ScoreResult], model: str
) -> ScoreResult:
    """`score(request)` with every remembered continuation looked up; `score` is asked only for the rest.

    The reply lists the continuations in the request's order, each a repeat or a fresh score; its meta
    is the engine's for the fresh ones (none when all were remembered) plus `memo_hits`. `model` names
    the model when none was asked.
    """
    started = time.perf_counter()
    known = [memo.get(request.prefix, text) for text in request.continuations]
    missing = tuple(
        dict.fromkeys(text for text, found in zip(request.continuations, known, strict=True) if found is None)
    )
    fresh: dict[str, ContinuationScore] = {}
    meta: dict[str, Any] = {}
    if missing:
        result = score(ScoreRequest(request.prefix, missing))
        model, meta = result.model, dict(result.meta)
        for text, value in zip(missing, result.scores, strict=True):
            memo.put(request.prefix, text, value)
            fresh[text] = value
    scores = tuple(found or fresh[text] for text, found in zip(request.continuations, known, strict=True))
    hits = sum(found is not None for found in known)
    return ScoreResult(scores, time.perf_counter() - started, model, meta | {"memo_hits": hits})
