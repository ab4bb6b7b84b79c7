"""The one interface every model backend implements, and the registry that finds them.

A backend is one class with one real method, `chat`. Backends are named by a spec string
`NAME[:ARG]` (e.g. `ollama:llama3.1`, `openai:gpt-4o@http://127.0.0.1:8080/v1`, `replay:runs/x/run.jsonl`)
and registered through the `llmnav.backends` entry-point group, so a third party adds one with `pip install`.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any, ClassVar, Literal

from llmnav.backends.prices import FREE_BACKENDS
from llmnav.core import plugins
from llmnav.core.chat import (
    AnswerKey,
    ChatRequest,
    ChatResult,
    ContinuationScore,
    Image,
    Message,
    Role,
    ScoreRequest,
    ScoreResult,
)
from llmnav.errors import BackendSpecError, BadInputError, ModelError

__all__ = [
    "AnswerKey",
    "Backend",
    "BackendStatus",
    "ChatRequest",
    "ChatResult",
    "Image",
    "Message",
    "Role",
    "ContinuationScore",
    "ScoreRequest",
    "ScoreResult",
    "get_backend",
    "parse_spec",
    "registry",
]


@dataclass(frozen=True)
class BackendStatus:
    """What `llmnav backends` shows for one backend."""

    ready: bool
    detail: str  # e.g. "server reachable at http://127.0.0.1:11434", "GEMINI_API_KEY not set"


@dataclass(frozen=True)
class Check:
    """One line of `llmnav backends --check SPEC`."""

    name: str  # what was checked: "reachable", "model present", "accepts images", ...
    ok: bool | None  # None: not checked (it does not apply, or an earlier check made it moot)
    detail: str


class Backend(ABC):
    """A chat model. Subclasses set `name`, parse their spec argument in `__init__` and implement `chat`."""

    name: ClassVar[str]
    default_arg: ClassVar[str | None] = None
    description: ClassVar[str] = ""
    # Whether images in messages reach the model. An instance may differ from its class (a replay takes
    # the recording's), so planners read it from the backend object they were given.
    multimodal: bool = False
    deterministic: ClassVar[bool] = False  # same request -> same reply (replay, local at temperature 0)
    # The model computes inside this Python process and holds the GIL for stretches of its work, so a
    # real-time loop runs it in a process of its own (llmnav.backends.isolated); rebuilt there from
    # `spec` and `options`.
    engine_in_process: ClassVar[bool] = False
    # Per instance: when the server turns out to take no images, go on without them instead of stopping
    # (the HTTP backends honour it; the runner sets it from `--drop-images`).
    drop_images: bool = False

    def __init__(self, arg: str | None = None, **options: Any) -> None:
        self.arg = arg if arg else self.default_arg
        self.options = options

    @abstractmethod
    def chat(self, request: ChatRequest) -> ChatResult:
        """Send one request; raise `ModelError` after the last failed attempt."""

    @property
    def can_score(self) -> bool:
        """Whether `score` works: the backend returns log-probabilities of given continuations.

        Per instance: a replay scores when its recording did, an HTTP backend when its server does.
        """
        return False

    def score(self, request: ScoreRequest) -> ScoreResult:
        """Each continuation's summed log-probability after `request.prefix`; `ModelError` when unsupported."""
        raise ModelError(f"{self.spec} cannot score continuations (it only generates text)")

    def check_schema(self, schema: dict[str, Any]) -> None:  # noqa: B027 - most backends compile nothing
        """Raise `ModelError` now when this backend cannot constrain answers to `schema`.

        Called before an episode that relies on constrained answers; a server-side backend's schema
        errors surface on the first request instead, and its answers are checked after decoding anyway.
        """

    @classmethod
    def status(cls, arg: str | None = None) -> BackendStatus:
        """Whether this backend could run now (cheap: no generation)."""
        return BackendStatus(True, "")

    @classmethod
    def check_arg(cls, arg: str | None) -> None:
        """Raise `BackendSpecError` now for an argument no run could use (a sweep checks before any folder)."""
        return  # most backends check their argument when built

    @classmethod
    def check(cls, arg: str | None = None) -> list[Check]:
        """What `llmnav backends --check` reports for this spec (HTTP backends probe their server)."""
        status = cls.status(arg)
        return [Check("ready", status.ready, status.detail)]

    @property
    def spec(self) -> str:
        """The spec string that recreates this backend (never contains secrets)."""
        return f"{self.name}:{self.arg}" if self.arg else self.name

    def billing(self) -> dict[str, Any]:
        """Who bills this backend's calls, for the run's configuration line (`llmnav.backends.prices`).

        {"free": why} or {"provider": backend name, "model": name}; a plugin llmnav does not know is
        {"unknown": why}, so its runs cost "unknown", never 0.
        """
        if self.name in FREE_BACKENDS:
            return {"free": f"{self.name} backend"}
        return {"unknown": f"{self.name}: a backend llmnav has no prices for"}

    def use_cache(self, cache: Any) -> bool:
        """Serve repeated requests from a reply cache (`llmnav.backends.cache.ReplyCache`); False: not cached.

        Only backends that pay per request over HTTP cache; the others compute (or replay) every answer.
        """
        return False

    @property
    def caching(self) -> bool:
        """Whether this backend's requests go through a reply cache."""
        return getattr(self, "reply_cache", None) is not None

    def close(self) -> None:  # noqa: B027 - optional hook, most backends hold nothing
        """Release connections or model memory."""

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.spec}>"


def request_modality(backend: Backend, camera: tuple[int, int] | None) -> dict[str, Any]:
    """What the run's requests carried, for the config line: `modality` and the `attachments` the model got.

    `camera` is the camera's (width, height) [px] when the planner senses images. A text-only backend gets
    no attachment even if a planner puts the frame in a message (the backend drops it). Replay reads
    `modality` back, so a replay asks exactly what the recorded backend was asked.
    """
    multimodal = bool(backend.multimodal)
    attachments = [f"camera image {camera[0]}x{camera[1]} JPEG"] if multimodal and camera else []
    return {"modality": "multimodal" if multimodal else "text", "attachments": attachments}


BACKEND_GROUP = "llmnav.backends"


def _not_a_backend(target: Any) -> str | None:
    return None if isinstance(target, type) and issubclass(target, Backend) else "is not a llmnav Backend subclass"


def registry() -> dict[str, type[Backend]]:
    """Every backend under the `llmnav.backends` entry-point group that loads; broken ones are left out.

    `llmnav backends` loads them one by one to show the broken ones with their reason.
    """
    names = plugins.usable(BACKEND_GROUP, "backend", _not_a_backend)
    return {name: plugins.load(BACKEND_GROUP, "backend", name, _not_a_backend) for name in names}


def registered_backends() -> list[str]:
    """Every name registered under `llmnav.backends` (broken ones too), sorted."""
    return sorted(plugins.registrations(BACKEND_GROUP))


def backend_source(backend: Backend) -> str:
    """The distribution and version that supplied `backend`'s class ("llmnav 0.1.0"), for the run log.

    A backend built by hand from a class no entry point names (tests, notebooks) says so, with the class.
    """
    name = parse_spec(backend.spec)[0]
    try:
        registered = plugins.load(BACKEND_GROUP, "backend", name, _not_a_backend)
    except BadInputError:
        registered = None
    if registered is type(backend):
        return plugins.find(BACKEND_GROUP, "backend", name).source
    return f"not registered ({type(backend).__module__}.{type(backend).__qualname__})"


def parse_spec(spec: str) -> tuple[str, str | None]:
    """Split `NAME[:ARG]` into name and argument."""
    name, _, arg = spec.strip().partition(":")
    return name.lower(), (arg or None)


Answerer = Literal["model", "policy", "oracle"]
POLICY_BACKEND = "policy"  # null policies and oracle answers: no model behind them
ORACLE_POLICY = "oracle"  # the policy that answers from the ground truth: a ceiling, not a floor


def answerer(spec: str) -> Answerer:
    """Who answers under a backend spec: a model, a null policy, or oracle answers (`policy:oracle[:...]`)."""
    name, arg = parse_spec(spec)
    if name != POLICY_BACKEND:
        return "model"
    return "oracle" if (arg or "").strip().lower().partition(":")[0] == ORACLE_POLICY else "policy"


def backend_class(spec: str) -> tuple[type[Backend], str | None]:
    """The class a spec string names and the spec's argument (only that backend's module is imported)."""
    name, arg = parse_spec(spec)
    known = registered_backends()
    if name not in known:
        raise BackendSpecError(f"unknown backend '{name}' in '{spec}' (known: {', '.join(known)})")
    try:
        cls: type[Backend] = plugins.load(BACKEND_GROUP, "backend", name, _not_a_backend)
    except BadInputError as err:
        raise BackendSpecError(str(err)) from None
    return cls, arg


def get_backend(spec: str, **options: Any) -> Backend:
    """Instantiate the backend a spec string names."""
    cls, arg = backend_class(spec)
    return cls(arg, **options)
