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
- `figures(record, out_dir)`: extra figures, written only when plots are on;
- `oracle_answers(truth, options)`: the answers a perfect model would give to its requests (an
  `AnswerKey` built from `GroundTruth`), which the `policy:oracle` backend returns: its ceiling.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field, replace
from importlib.metadata import entry_points
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar, Generic, Literal, Protocol, TypeVar, get_args, get_origin

from pydantic import BaseModel, ConfigDict, Field, field_validator

from llmnav.declarations import NOTHING_DECLARED, Declarations
from llmnav.errors import BadInputError, redact_secrets
from llmnav.planners import DEFAULT_PLANNER

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
# How a model-driven choice is made: scored option texts, generated answers, or scores where the backend can.
Decide = Literal["auto", "score", "generate"]




class DriveOptions(BaseModel):
    """The options every episode has: what the runner, the observation and the guard read.

    A planner's own options extend this model: its `Options` class (pydantic, `extra="forbid"`, a unit in
    every field's description), the way a model in simonw/llm owns its `Options`. `drive_options` builds
    the right one from a planner name; the run's config line logs it in full.
    """

    model_config = ConfigDict(extra="forbid")

    planner: str = Field(default=DEFAULT_PLANNER, description="a name registered under the llmnav.planners group")
    information: Information | None = Field(
        default=None, description="map | sensed | oracle; None: the planner's default for the scenario"
    )
    sensing: tuple[Literal["lidar", "image", "detections"], ...] = Field(
        default=("lidar", "image"), description="what each observation holds"
    )
    lidar_sectors: int = Field(default=8, ge=1, le=72, description="[sectors] in the LiDAR summary")
    lidar_fov_deg: float = Field(default=90.0, gt=0, le=360, description="[deg] LiDAR summary field of view")
    max_iterations: int = Field(default=30, ge=1, description="[decisions] before the episode fails")
    max_corrections: int = Field(default=3, ge=0, description="[turns] guard corrections per model answer")
    seed: int = Field(default=0, description="simulation and model seed")
    realtime: bool = Field(default=False, description="pace the simulation to the wall clock")
    temperature: float = Field(default=0.0, ge=0, le=2, description="model sampling temperature")
    max_tokens: int = Field(default=512, ge=16, description="[tokens] per model answer")
    image_width: int = Field(default=640, ge=16, le=640, description="[px] camera image width")
    image_height: int = Field(default=480, ge=16, le=480, description="[px] camera image height")
    drop_images: bool = Field(default=False, description="a server that rejects images: go on without them")
    obstacles: tuple[tuple[float, float], ...] = Field(
        default=(), description="[m] unexpected box obstacles dropped at X,Y"
    )

    # Input keys beyond the fields that a before-validator maps onto fields (e.g. `ttl=auto`).
    input_aliases: ClassVar[frozenset[str]] = frozenset()

    @classmethod
    def input_keys(cls) -> frozenset[str]:
        """Every key `-o KEY=VALUE`, a grid or `drive_options` may give this model."""
        return frozenset(cls.model_fields) | cls.input_aliases

    @field_validator("planner")
    @classmethod
    def _registered(cls, name: str) -> str:
        known = planner_names()
        if name not in known:
            raise ValueError(f"unknown planner '{name}' (registered: {', '.join(known)})")
        return name


class ChoiceOptions(DriveOptions):
    """Options of a planner whose model chooses among options: by scores or by generated answers."""

    decide: Decide = Field(
        default="auto", description="score option texts | generate an answer | auto: score if the backend can"
    )


OptionsT = TypeVar("OptionsT", bound=DriveOptions)

# Options every planner honours (or that describe the episode rather than the planner).
COMMON_OPTIONS: frozenset[str] = frozenset({"planner", "seed", "realtime", "obstacles", "information"})
# The options of a model-driven planner that asks once per decision.
MODEL_OPTIONS: frozenset[str] = frozenset({"temperature", "max_tokens", "max_corrections"})


def drive_options(planner: str = DEFAULT_PLANNER, **fields: Any) -> DriveOptions:
    """The options of one episode of `planner`: its own `Options` model, validated (pydantic errors)."""
    return planner_class(planner).Options.model_validate({"planner": planner, **fields})


def as_planner_options(options: DriveOptions) -> DriveOptions:
    """`options` as its planner's own `Options` model (a bare `DriveOptions` takes the planner's defaults)."""
    cls = planner_class(options.planner).Options
    if isinstance(options, cls):
        return options
    return cls.model_validate(options.model_dump(exclude_unset=True) | {"planner": options.planner})


def option_value(model: type[DriveOptions], name: str, value: Any) -> Any:
    """A value from a flag or a grid as option `name` takes it.

    A tuple of words is written `lidar+image` (or `lidar,image` on `-o`); a number where the option takes
    words like "0" is that word (YAML reads `history: [0, 2]` as numbers). Anything else goes to pydantic.
    """
    field = model.model_fields.get(name)
    if field is None or isinstance(value, bool):
        return value
    annotation = field.annotation
    args = get_args(annotation)
    if get_origin(annotation) is tuple and isinstance(value, str) and args and get_origin(args[0]) is not tuple:
        parts = tuple(part.strip() for part in value.replace(",", "+").split("+") if part.strip())
        if len(set(parts)) != len(parts):
            raise BadInputError(f"{name} {value!r}: lists a value (a sensor, a word) more than once")
        return parts
    if get_origin(annotation) is Literal and all(isinstance(a, str) for a in args) and isinstance(value, int):
        return str(value)
    return value


def planner_options(planner: str, given: dict[str, Any]) -> tuple[DriveOptions, list[str]]:
    """`planner`'s options from the keys a user gave, and the given keys it ignores (for a note).

    A key that no registered planner takes is a typo: `BadInputError` naming what this planner takes.
    Values are validated by pydantic (a `ValidationError` names the key).
    """
    cls = planner_class(planner)
    ignored = cls.unused_options(set(given))
    for key in ignored:  # ignored, but a bad value is still bad input (and a typo of a key an error)
        check_option_value(key, given[key], planner)
    keys = cls.Options.input_keys()
    values = {k: option_value(cls.Options, k, v) for k, v in given.items() if k in keys}
    return cls.Options.model_validate({**values, "planner": planner}), ignored


def check_option_value(key: str, value: Any, planner: str) -> None:
    """Validate one option with a planner that takes it (`planner` first); a key none takes is refused.

    Raises `BadInputError` for an unknown key and pydantic's `ValidationError` for a bad value.
    """
    takers = [planner, *planner_names()]
    for name in takers:
        model = planner_class(name).Options
        if key in model.input_keys():
            model.model_validate({"planner": name, key: option_value(model, key, value)})
            return
    takes = ", ".join(option_names(planner))
    raise BadInputError(f"option {key!r}: no planner takes it; planner '{planner}' takes: {takes}")


def option_names(planner: str) -> list[str]:
    """Every option key `planner` takes (its `Options` fields and input aliases), sorted."""
    return sorted(planner_class(planner).Options.input_keys())


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
class EpisodeContext(Generic[OptionsT]):
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
    options: OptionsT  # the planner's own `Options` model
    view: View = field(default_factory=NullView)
    # What the planner may know (llmnav.knowledge); with "sensed", `scenario` is a view without positions.
    information: Information = "oracle"

    def chat(self, request: ChatRequest, purpose: str, step: int | None) -> ChatResult:
        """Send `request` to the backend, logged as an `llm_call` event (see `llmnav.observe.call_model`)."""
        from llmnav.observe import call_model

        return call_model(self, request, purpose, step)

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


def decides_by_scores(options: ChoiceOptions, backend: Backend | None) -> bool:
    """Whether `decide` asks for scored choices with this backend (`auto`: if the backend can score)."""
    if options.decide == "generate" or backend is None:
        return False
    return options.decide == "score" or backend.can_score


class Planner(ABC, Generic[OptionsT]):
    """One navigation strategy. Stateless between episodes; all state lives in `run`."""

    name: ClassVar[str]
    needs_backend: ClassVar[bool] = True
    Options: ClassVar[type[DriveOptions]] = DriveOptions  # its own options model (a DriveOptions subclass)
    options: ClassVar[frozenset[str]] = frozenset()  # the shared DriveOptions fields it reads, beyond COMMON_OPTIONS
    # What it can run with (llmnav.knowledge); the first is its default where no map is published.
    information_modes: ClassVar[tuple[Information, ...]] = ("oracle",)
    grid_factors: ClassVar[tuple[str, ...]] = ()  # option keys worth varying in an ablation (its own first)
    # its score tables, decision noun and view sections (llmnav.declarations): read above it, never by name
    declares: ClassVar[Declarations] = NOTHING_DECLARED
    paces_itself: ClassVar[bool] = False  # paces its own loop under --realtime (the world does not)

    def requires_backend(self, options: OptionsT) -> bool:
        """Whether this episode needs a model (the runner creates no backend otherwise)."""
        return self.needs_backend

    def templates(self, options: OptionsT) -> list[str]:
        """Prompt templates this planner renders (their hashes go into the config line)."""
        return []

    def check_backend(self, backend: Backend, options: OptionsT) -> None:  # noqa: B027 - most need nothing
        """Raise `BadInputError` when this episode cannot run on `backend` (before any run folder exists)."""

    @abstractmethod
    def run(self, ctx: EpisodeContext[OptionsT]) -> EpisodeOutcome:
        """Drive one episode to its end; log every event through `ctx.log`; never print."""

    def summarize(self, record: RunRecord, scenario: Scenario, task: Task) -> dict[str, Any]:
        """Planner metrics computed from the closed run log, merged into the summary's planner metrics."""
        return {}

    def figures(self, record: RunRecord, out_dir: Path) -> list[Path]:
        """Write this planner's own figures into `out_dir` (called only when plots are on)."""
        return []

    def oracle_answers(self, truth: GroundTruth, options: OptionsT) -> AnswerKey | None:
        """The answers a perfect model would give this episode's requests (None: the planner offers none)."""
        return None

    @classmethod
    def offers_oracle_answers(cls) -> bool:
        """Whether `oracle_answers` is implemented (checked before any run folder exists)."""
        return cls.oracle_answers is not Planner.oracle_answers

    @classmethod
    def unused_options(cls, given: set[str]) -> list[str]:
        """The option keys among `given` that this planner ignores (shared ones it does not read, or unknown)."""
        own = cls.Options.input_keys() - set(DriveOptions.model_fields)
        applies = COMMON_OPTIONS | cls.options | own
        return sorted(name for name in given if name not in applies)


def _registered_points() -> dict[str, Any]:
    return {ep.name: ep for ep in entry_points(group=PLANNER_GROUP)}


def planner_names() -> list[str]:
    """Every planner name registered under the `llmnav.planners` entry-point group, sorted."""
    return sorted(_registered_points())


def planner_class(name: str) -> type[Planner[Any]]:
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


def get_planner(name: str) -> Planner[Any]:
    """Instantiate a planner by its registered name."""
    return planner_class(name)()
