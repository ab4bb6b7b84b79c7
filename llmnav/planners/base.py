"""The planner interface, the episode context every planner receives, and the planner registry.

Planners plug in like backends: each is a `Planner` subclass registered under the `llmnav.planners`
entry-point group (the built-ins are registered the same way in llmnav's own pyproject.toml), so a third
party adds one with `pip install`. A planner declares what it needs and does through class attributes
and small hooks, so nothing above it names it:

- `options`: the `DriveOptions` fields that apply to it (beyond `COMMON_OPTIONS`); `unused_options`
  tells `drive` and `ablate` which given flags it ignores;
- `paces_itself`: it paces its own control loop in `--realtime` (the world then does not);
- `templates(options)`: the prompt templates it renders (hashed into the run's config line);
- `summarize(record, scenario, task)`: planner metrics computed from the finished run log;
- `figure_kinds`: standard figures the runner draws for it from its run log when plots are on (a kind
  names a figure, e.g. `velocity_profile` from `cmd` records, never a planner);
- `figures(record, out_dir)`: extra figures it draws itself, written only when plots are on;
- `oracle_answers(truth, options)`: the answers a perfect model would give to its requests (an
  `AnswerKey` built from `GroundTruth`), which the `policy:oracle` backend returns: its ceiling.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field, replace
from importlib.metadata import entry_points
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, ClassVar, Literal, Protocol

from pydantic import BaseModel, ConfigDict, Field, field_validator

from llmnav.errors import BadInputError, redact_secrets

if TYPE_CHECKING:
    from llmnav.backends.base import Backend
    from llmnav.chat import AnswerKey, ChatRequest, ChatResult, ScoreRequest, ScoreResult
    from llmnav.geometry import Pose2D
    from llmnav.guard.view import PlannerWorld
    from llmnav.runlog import RunLog, RunRecord
    from llmnav.scenario import Scenario, Task

PLANNER_GROUP = "llmnav.planners"
Outcome = Literal["completed", "failed", "aborted"]
# What a planner may know (see llmnav.knowledge): a published map, only its own sensors, or ground truth.
Information = Literal["map", "sensed", "oracle"]
MenuOrder = Literal["distance", "relevance"]
# How a model-driven choice is made: scored option texts, generated answers, or scores where the backend can.
Decide = Literal["auto", "score", "generate"]


class DriveOptions(BaseModel):
    """Every knob of one episode (the `llmnav drive` flags); logged in full in the run's config line."""

    model_config = ConfigDict(extra="forbid")

    planner: str = "hybrid"  # a name registered under the `llmnav.planners` entry-point group
    information: Information | None = None  # None: the planner's default for the scenario (llmnav.knowledge)
    menu_order: MenuOrder = "distance"  # hybrid: neutral by distance, or "relevance" (task-name matching first)
    decide: Decide = "auto"  # hybrid: score option texts | generate an option number | auto: score if the backend can
    sensing: tuple[Literal["lidar", "image", "detections"], ...] = ("lidar", "image")
    lidar_sectors: int = Field(default=8, ge=1, le=72)
    lidar_fov_deg: float = Field(default=90.0, gt=0, le=360)
    prompt: str = "full"
    history: Literal["all", "0", "1", "2"] = "all"
    self_check: bool = False
    max_iterations: int = Field(default=30, ge=1)
    max_corrections: int = Field(default=3, ge=0)  # guard correction turns per step
    max_vetoes: int = Field(default=3, ge=0)  # safety-veto negotiation turns per step
    max_step_m: float = Field(default=5.0, gt=0)  # FRONT/BACK upper bound
    seed: int = 0
    realtime: bool = False
    temperature: float = Field(default=0.0, ge=0, le=2)
    max_tokens: int = Field(default=512, ge=16)
    image_width: int = Field(default=640, ge=16, le=640)
    image_height: int = Field(default=480, ge=16, le=480)
    drop_images: bool = False  # a model server that rejects images: go on without them instead of stopping
    # waypoints (source B)
    max_generations: int = Field(default=5, ge=1)
    max_replans: int = Field(default=5, ge=0)
    replan_cooldown_s: float = Field(default=5.0, ge=0)
    obstacles: tuple[tuple[float, float], ...] = ()
    preset_waypoints: tuple[tuple[float, float], ...] = ()  # `llmnav plan --execute`: a plan already made
    # fsm (source C)
    assist: Literal["none", "ema", "llm"] = "none"
    alpha: float = Field(default=0.5, ge=0, le=1)
    beta: float = Field(default=0.5, ge=0, le=1)
    ttl_ms: float = Field(default=500.0, gt=0)
    ttl_auto: bool = False  # `--ttl auto`: TTL from the observed model latencies (ttl_ms is the start)
    # Model latency charged to simulation time: the backend's figure, a replay's record, or fixed [ms].
    model_latency: Literal["measured", "recorded"] | Annotated[float, Field(ge=0, allow_inf_nan=False)] = (
        "measured"
    )
    max_ticks: int = Field(default=15000, ge=1)  # [ticks] 300 s of sim time at 50 Hz

    @field_validator("planner")
    @classmethod
    def _registered(cls, name: str) -> str:
        known = planner_names()
        if name not in known:
            raise ValueError(f"unknown planner '{name}' (registered: {', '.join(known)})")
        return name


# Options every planner honours (or that describe the episode rather than the planner).
COMMON_OPTIONS: frozenset[str] = frozenset({"planner", "seed", "realtime", "obstacles"})
# The options of a model-driven planner that asks once per decision.
MODEL_OPTIONS: frozenset[str] = frozenset({"temperature", "max_tokens", "max_corrections"})


@dataclass
class StepInfo:
    """What the live view shows after each decision."""

    step: int
    action: str
    reasoning: str = ""
    front_m: float | None = None
    latency_s: float | None = None
    vetoes: int = 0
    json_retries: int = 0


class View(Protocol):
    """Progress sink (rich live view, one-line progress, or nothing)."""

    def on_step(self, info: StepInfo) -> None:
        """Called after each decision."""


class NullView:
    """A view that shows nothing."""

    def on_step(self, info: StepInfo) -> None:
        """Ignore."""


class RedactedView:
    """A view whose steps show no secret: a model or server may echo the key back in its text."""

    def __init__(self, view: View, secrets: Iterable[str]) -> None:
        self.view = view
        self.secrets = tuple(secrets)

    def on_step(self, info: StepInfo) -> None:
        """Pass the step on with its text redacted (whole, before any view shortens it to a fragment)."""
        self.view.on_step(
            replace(
                info,
                action=redact_secrets(info.action, self.secrets),
                reasoning=redact_secrets(info.reasoning, self.secrets),
            )
        )


@dataclass
class EpisodeContext:
    """Everything a planner may use during one episode.

    `world` is the planner's view (`llmnav.guard.view.PlannerWorld`): sensors to read and the guarded
    motion layer; no raw simulator, robot or motion. `chat` and `event` make the context what
    `llmnav.guard.ask.ask_guarded` needs.
    """

    scenario: Scenario
    task: Task
    world: PlannerWorld
    backend: Backend | None
    log: RunLog
    options: DriveOptions
    view: View = field(default_factory=NullView)
    # What the planner may know (llmnav.knowledge); with "sensed", `scenario` is a view without positions.
    information: Information = "oracle"

    def chat(self, request: ChatRequest, purpose: str, step: int | None) -> ChatResult:
        """Send `request` to the backend, logged as an `llm_call` event (see `llmnav.observe.call_model`)."""
        from llmnav.observe import call_model

        return call_model(self, request, purpose, step)

    def decides_by_scores(self) -> bool:
        """Whether `--decide` asks for scored choices with this episode's backend (`auto`: if it can score)."""
        if self.options.decide == "generate" or self.backend is None:
            return False
        return self.options.decide == "score" or self.backend.can_score

    def score(self, request: ScoreRequest, step: int | None) -> ScoreResult:
        """Score continuations with the backend, logged as an `llm_call` event (`llmnav.observe.call_scorer`)."""
        from llmnav.observe import call_scorer

        return call_scorer(self, request, step)

    def event(self, kind: str, **fields: Any) -> None:
        """Log one event at the current simulated time."""
        self.log.sim_time = self.world.sim_time
        self.log.event(kind, **fields)


@dataclass(frozen=True)
class GroundTruth:
    """What an oracle answer key may read, and only it: the runner builds it for `policy:oracle` runs.

    The planner's own decisions never see it (they get `EpisodeContext`, cut to their information mode).
    """

    scenario: Scenario  # the full scenario, with the boxes `--obstacle` dropped
    task: Task
    pose: Callable[[], Pose2D]  # the robot's true pose now
    sim_time: Callable[[], float]  # [s] simulated time now


class GeneratedAnswers:
    """Base of an answer key for a planner that only asks for generated answers (never for scores)."""

    @property
    def can_score(self) -> bool:
        """No scores: the backend refuses scoring requests for this planner's oracle answers."""
        return False

    def scores(self, request: ScoreRequest) -> tuple[float, ...]:
        """Never called (see `can_score`)."""
        raise NotImplementedError(f"{type(self).__name__} answers no scoring requests")


@dataclass
class EpisodeOutcome:
    """How an episode ended; `metrics` holds planner-specific numbers for summary.json."""

    outcome: Outcome
    reason: str
    iterations: int = 0
    metrics: dict[str, Any] = field(default_factory=dict)


class Planner(ABC):
    """One navigation strategy. Stateless between episodes; all state lives in `run`."""

    name: ClassVar[str]
    needs_backend: ClassVar[bool] = True
    options: ClassVar[frozenset[str]] = frozenset()  # DriveOptions fields that apply, beyond COMMON_OPTIONS
    paces_itself: ClassVar[bool] = False  # paces its own loop under --realtime (the world does not)
    figure_kinds: ClassVar[tuple[str, ...]] = ()  # standard figures drawn from its log (llmnav.runner.FIGURES)

    def requires_backend(self, options: DriveOptions) -> bool:
        """Whether this episode needs a model (the runner creates no backend otherwise)."""
        return self.needs_backend

    def templates(self, options: DriveOptions) -> list[str]:
        """Prompt templates this planner renders (their hashes go into the config line)."""
        return []

    def check_backend(self, backend: Backend, options: DriveOptions) -> None:  # noqa: B027 - most need nothing
        """Raise `BadInputError` when this episode cannot run on `backend` (before any run folder exists)."""

    @abstractmethod
    def run(self, ctx: EpisodeContext) -> EpisodeOutcome:
        """Drive one episode to its end; log every event through `ctx.log`; never print."""

    def summarize(self, record: RunRecord, scenario: Scenario, task: Task) -> dict[str, Any]:
        """Planner metrics computed from the closed run log, merged into the summary's planner metrics."""
        return {}

    def figures(self, record: RunRecord, out_dir: Path) -> list[Path]:
        """Write this planner's own figures into `out_dir` (called only when plots are on)."""
        return []

    def oracle_answers(self, truth: GroundTruth, options: DriveOptions) -> AnswerKey | None:
        """The answers a perfect model would give this episode's requests (None: the planner offers none)."""
        return None

    @classmethod
    def offers_oracle_answers(cls) -> bool:
        """Whether `oracle_answers` is implemented (checked before any run folder exists)."""
        return cls.oracle_answers is not Planner.oracle_answers

    @classmethod
    def unused_options(cls, given: set[str]) -> list[str]:
        """The options among `given` (DriveOptions field names) that this planner ignores."""
        applies = COMMON_OPTIONS | cls.options
        return sorted(name for name in given if name not in applies)


def _registered_points() -> dict[str, Any]:
    return {ep.name: ep for ep in entry_points(group=PLANNER_GROUP)}


def planner_names() -> list[str]:
    """Every planner name registered under the `llmnav.planners` entry-point group, sorted."""
    return sorted(_registered_points())


def planner_class(name: str) -> type[Planner]:
    """The planner class registered as `name` (only its module is imported)."""
    points = _registered_points()
    if name not in points:
        raise BadInputError(f"unknown planner '{name}' (registered: {', '.join(sorted(points))})")
    try:
        cls = points[name].load()
    except Exception as err:  # noqa: BLE001 - a broken third-party plugin: one line, not a traceback
        raise BadInputError(f"planner '{name}' failed to load: {type(err).__name__}: {err}") from None
    if not (isinstance(cls, type) and issubclass(cls, Planner)):
        raise BadInputError(f"planner '{name}' is not a llmnav Planner subclass")
    return cls


def inapplicable_options(planner: str, given: set[str]) -> list[str]:
    """The option names among `given` that planner `planner` ignores (for a one-line note to the user)."""
    return planner_class(planner).unused_options(given)


def changed_options(options: DriveOptions) -> set[str]:
    """The fields of `options` that differ from their defaults (what the user actually set)."""
    defaults = DriveOptions.model_construct()
    return {name for name in DriveOptions.model_fields if getattr(options, name) != getattr(defaults, name)}


def get_planner(name: str) -> Planner:
    """Instantiate a planner by its registered name."""
    return planner_class(name)()
