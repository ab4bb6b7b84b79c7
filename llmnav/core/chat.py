"""Chat types shared by planners, backends, the run log and the simulator: a leaf module (imports nothing of llmnav).

`Message` (a role, text and images), `Image` (a base64 JPEG), `ChatRequest` (what a planner asks) and
`ChatResult` (a model's reply and its cost); `ScoreRequest` and `ScoreResult` (log-probabilities of
given continuations); `AnswerKey` (the answers a perfect model would give, which `policy:oracle` returns).
"""

from __future__ import annotations

import base64
import hashlib
from dataclasses import dataclass, field
from typing import Any, Literal, Protocol, runtime_checkable

Role = Literal["system", "user", "assistant"]


@dataclass(frozen=True)
class Image:
    """A JPEG image, base64-encoded, as sent to multimodal models."""

    jpeg_b64: str

    @property
    def sha256(self) -> str:
        """Content hash: run logs store each image once, as a file named by it."""
        return hashlib.sha256(self.jpeg_b64.encode("ascii")).hexdigest()

    @property
    def jpeg_bytes(self) -> bytes:
        """The raw JPEG bytes."""
        return base64.b64decode(self.jpeg_b64)


@dataclass(frozen=True)
class Message:
    """One chat message: a role, its text and optional images."""

    role: Role
    text: str
    images: tuple[Image, ...] = ()

    def to_log(self) -> dict[str, Any]:
        """Log form: images by hash, never inline (they are written beside the log)."""
        out: dict[str, Any] = {"role": self.role, "text": self.text}
        if self.images:
            out["images"] = [img.sha256 for img in self.images]
        return out


@dataclass(frozen=True)
class ChatRequest:
    """What a planner asks of a model."""

    messages: tuple[Message, ...]
    json_schema: dict[str, Any] | None = None  # the answer's JSON Schema (constrained decoding where supported)
    temperature: float = 0.0
    max_tokens: int = 512
    seed: int | None = None

    def to_log(self) -> dict[str, Any]:
        """Log form of the request (the replay backend compares this)."""
        return {
            "messages": [m.to_log() for m in self.messages],
            "json_schema": self.json_schema,
            "temperature": self.temperature,
            "max_tokens": self.max_tokens,
            "seed": self.seed,
        }


@dataclass
class ChatResult:
    """A model's reply and what it cost."""

    text: str
    latency_s: float  # [s] wall time of the call, retries included
    model: str
    prompt_tokens: int | None = None
    completion_tokens: int | None = None
    meta: dict[str, Any] = field(default_factory=dict)  # provider details (finish reason, attempts, ...)

    @property
    def logged_latency_s(self) -> float:
        """The latency as the log keeps it (0.1 ms), which is what a replay of the run will report."""
        return round(self.latency_s, 4)

    def to_log(self) -> dict[str, Any]:
        """Log form of the reply."""
        return {
            "text": self.text,
            "latency_s": self.logged_latency_s,
            "model": self.model,
            "prompt_tokens": self.prompt_tokens,
            "completion_tokens": self.completion_tokens,
            "meta": self.meta,
        }


@dataclass(frozen=True)
class ScoreRequest:
    """Ask how likely each continuation is after a plain-text prefix (no chat template).

    Planners use it to score option texts instead of asking a small model to write an option number
    (SayCan scores skills this way). Each continuation should begin with the space that separates it
    from the prefix (" fire extinguisher"), so it tokenises as it would in running text.
    """

    prefix: str
    continuations: tuple[str, ...]
    # [m] where each continuation's place lies on the planner's map (frontiers): a model never reads it;
    # oracle answers, which may read ground truth, judge a place by where it is, not by its words
    places: tuple[tuple[float, float], ...] = ()

    def to_log(self) -> dict[str, Any]:
        """Log form: a run log keeps it like a chat request (one user message), so replay compares it alike."""
        logged: dict[str, Any] = {
            "messages": [{"role": "user", "text": self.prefix}],
            "continuations": list(self.continuations),
        }
        if self.places:
            logged["places"] = [[round(x, 3), round(y, 3)] for x, y in self.places]
        return logged


@dataclass(frozen=True)
class ContinuationScore:
    """One continuation's summed log-probability [nats] and the number of tokens it took."""

    logprob: float
    tokens: int


@dataclass
class ScoreResult:
    """The scores of a `ScoreRequest`, in the order of its continuations, and what they cost."""

    scores: tuple[ContinuationScore, ...]
    latency_s: float  # [s] wall time of the call
    model: str
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        # Decisions use the scores exactly as the log keeps them, so a strict replay decides the same.
        self.scores = tuple(ContinuationScore(round(float(s.logprob), 6), int(s.tokens)) for s in self.scores)

    @property
    def logged_latency_s(self) -> float:
        """The latency as the log keeps it (0.1 ms)."""
        return round(self.latency_s, 4)

    def to_log(self) -> dict[str, Any]:
        """Log form (`text` stays empty: a scoring call writes nothing)."""
        return {
            "text": "",
            "scores": [[s.logprob, s.tokens] for s in self.scores],
            "latency_s": self.logged_latency_s,
            "model": self.model,
            "meta": self.meta,
        }


@runtime_checkable
class AnswerKey(Protocol):
    """The answers a perfect model would give to one planner's requests in one episode (its ceiling).

    A planner builds it from ground truth (its `oracle_answers` hook) and the `policy:oracle` backend
    returns its answers: they travel the road of every model's answers (request, guard, veto, log, strict
    replay), and the backend itself never reads the simulator.
    """

    @property
    def can_score(self) -> bool:
        """Whether `scores` answers scoring requests (planners that decide by scored option texts)."""

    def answer(self, request: ChatRequest) -> str:
        """The reply text a perfect model would write to `request`."""

    def scores(self, request: ScoreRequest) -> tuple[float, ...]:
        """A log-probability [nats] per continuation of `request` that ranks them as a perfect model would."""
