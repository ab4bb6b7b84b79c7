"""The planner interface, the episode context every planner receives, and the planner registry.

Planners plug in like backends: each is a `Planner` subclass registered under the `llmnav.planners`
entry-point group (the built-ins are registered the same way in llmnav's own pyproject.toml), so a third
party adds one with `pip install`. A planner declares what it needs and does through class attributes
and small hooks, so nothing above it names it:

- `Options`: its own pydantic options model, a `DriveOptions` subclass (`extra="forbid"`, a unit in every
  field's description); `drive -o KEY=VALUE` and ablation factors take any of its keys;
- `options`: the shared `DriveOptions` fields it reads; `unused_options` tells `drive` and `ablate`
  which given keys it ignores;
- `information_modes`: what it may know (read by `llmnav.world.knowledge`); `grid_factors`: options worth
  varying; `condition_keys`: the options that tell its experimental conditions apart (what `score` groups
  runs by; `llmnav.scoring.metrics.condition_keys` joins every planner's); `declares`: its score tables
  and how the view reads its decisions (`llmnav.core.declarations`);
- `paces_itself`: it paces its own control loop in `--realtime` (the world then does not);
- `templates(options)`: the prompt templates it renders (hashed into the run's config line);
  `prompt_package`: the package whose `prompts/` folder holds them (None: llmnav's bundled one), so a
  plug-in ships its own and renders them with `self.render_prompt`;
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
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar, Generic, Literal, Protocol

from llmnav.core import plugins
from llmnav.core.declarations import NOTHING_DECLARED, Declarations
from llmnav.errors import BadInputError, redact_secrets
from llmnav.planners import prompting
from llmnav.planners.observe import call_model, call_scorer
from llmnav.planners.options import (
    COMMON_OPTIONS,
    DEFAULT_PLANNER,
    MODEL_OPTIONS,
    PLANNER_GROUP,
    ChoiceOptions,
    CliFlag,
    Decide,
    DriveOptions,
    Information,
    OptionsT,
    decides_by_scores,
    fallback_mark,
    option_value,
    planner_names,
)

__all__ = [
    "COMMON_OPTIONS",
    "DEFAULT_PLANNER",
    "MODEL_OPTIONS",
    "PLANNER_GROUP",
    "ChoiceOptions",
    "CliFlag",
    "Decide",
    "DriveOptions",
    "EpisodeContext",
    "EpisodeOutcome",
    "GeneratedAnswers",
    "GroundTruth",
    "Information",
    "NullView",
    "OptionsT",
    "Outcome",
    "Planner",
    "RedactedView",
    "StepInfo",
    "View",
    "as_planner_options",
    "broken_planners",
    "check_option_value",
    "decides_by_scores",
    "drive_options",
    "fallback_mark",
    "get_planner",
    "inapplicable_options",
    "option_names",
    "option_value",
    "planner_class",
    "planner_names",
    "planner_options",
    "planner_source",
    "planner_taking",
    "usable_planner_names",
]

if TYPE_CHECKING:
    from llmnav.backends.base import Backend
    from llmnav.core.chat import AnswerKey, ChatRequest, ChatResult, ScoreRequest, ScoreResult
    from llmnav.core.geometry import Pose2D
    from llmnav.guard.view import PlannerWorld
    from llmnav.runs.runlog import RunLog, RunRecord
    from llmnav.world.scenario import Scenario, Task

# "not_found": the planner looked everywhere it could and says so, rather than finishing somewhere wrong
Outcome = Literal["completed", "failed", "not_found", "aborted"]


def drive_options(planner: str = DEFAULT_PLANNER, **fields: Any) -> DriveOptions:
    """The options of one episode of `planner`: its own `Options` model, validated (pydantic errors)."""
    return planner_class(planner).Options.model_validate({"planner": planner, **fields})


def as_planner_options(options: DriveOptions) -> DriveOptions:
    """`options` as its planner's own `Options` model (a bare `DriveOptions` takes the planner's defaults)."""
    cls = planner_class(options.planner).Options
    if isinstance(options, cls):
        return options
    return cls.model_validate(options.model_dump(exclude_unset=True) | {"planner": options.planner})


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


def check_option_value(key: str, value: Any, planner: str) -> Any:
    """Validate one option with a planner that takes it (`planner` first); a key none takes is refused.

    Returns the value as the options model holds it (`"08"` → 8), so two spellings of one value compare
    equal; an input alias that is no field returns the value as given. Raises `BadInputError` for an
    unknown key and pydantic's `ValidationError` for a bad value.
    """
    taker = planner_taking(key, first=planner)
    if taker is None:
        takes = ", ".join(option_names(planner))
        raise BadInputError(f"option {key!r}: no planner takes it; planner '{planner}' takes: {takes}")
    model = planner_class(taker).Options
    validated = model.model_validate({"planner": taker, key: option_value(model, key, value)})
    return getattr(validated, key) if key in model.model_fields else value


def planner_taking(key: str, first: str | None = None) -> str | None:
    """A registered planner that takes option `key` (`first` when it does), or None when none does."""
    for name in [first, *usable_planner_names()] if first else usable_planner_names():
        if key in planner_class(name).Options.input_keys():
            return name
    return None


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
    # What the planner may know (llmnav.world.knowledge); with "sensed", `scenario` is a view without positions.
    information: Information = "oracle"

    def chat(self, request: ChatRequest, purpose: str, step: int | None) -> ChatResult:
        """Send `request` to the backend, logged as an `llm_call` event (see `llmnav.planners.observe.call_model`)."""
        return call_model(self, request, purpose, step)

    def score(self, request: ScoreRequest, step: int | None) -> ScoreResult:
        """Score continuations with the backend, logged as an `llm_call` event (`observe.call_scorer`)."""
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


class Planner(ABC, Generic[OptionsT]):
    """One navigation strategy. Stateless between episodes; all state lives in `run`."""

    name: ClassVar[str]
    needs_backend: ClassVar[bool] = True
    Options: ClassVar[type[DriveOptions]] = DriveOptions  # its own options model (a DriveOptions subclass)
    options: ClassVar[frozenset[str]] = frozenset()  # the shared DriveOptions fields it reads, beyond COMMON_OPTIONS
    # What it can run with (llmnav.world.knowledge); the first is its default where no map is published.
    information_modes: ClassVar[tuple[Information, ...]] = ("oracle",)
    # A baseline that plans on the true map in every information mode: `sensed` then senses only its pose
    knows_map: ClassVar[bool] = False
    grid_factors: ClassVar[tuple[str, ...]] = ()  # option keys worth varying in an ablation (its own first)
    condition_keys: ClassVar[tuple[str, ...]] = ()  # option keys that make a run's condition (beside planner, backend)
    # its score tables, decision noun and view sections (llmnav.core.declarations): read above it, never by name
    declares: ClassVar[Declarations] = NOTHING_DECLARED
    paces_itself: ClassVar[bool] = False  # paces its own loop under --realtime (the world does not)
    figure_kinds: ClassVar[tuple[str, ...]] = ()  # standard figures drawn from its log (llmnav.runs.runner.FIGURES)
    # the package whose prompts/ folder holds its templates (llmnav.planners.prompting); None: llmnav's bundled one
    prompt_package: ClassVar[str | None] = None

    def requires_backend(self, options: OptionsT) -> bool:
        """Whether this episode needs a model (the runner creates no backend otherwise)."""
        return self.needs_backend

    def templates(self, options: OptionsT) -> list[str]:
        """Prompt templates this planner renders (their hashes go into the config line)."""
        return []

    @classmethod
    def render_prompt(cls, name: str, **values: Any) -> str:
        """Its template `name` filled with `values`, read from its `prompt_package`."""
        return prompting.render(name, cls.prompt_package, **values)

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


def _not_a_planner(target: Any) -> str | None:
    return None if isinstance(target, type) and issubclass(target, Planner) else "is not a llmnav Planner subclass"


def planner_class(name: str) -> type[Planner[Any]]:
    """The planner class registered as `name` (only its module is imported; see `llmnav.core.plugins`).

    BadInputError when no distribution registers it, two do, or it does not load as a Planner subclass.
    """
    cls: type[Planner[Any]] = plugins.load(PLANNER_GROUP, "planner", name, _not_a_planner)
    return cls


def usable_planner_names() -> list[str]:
    """The registered planners that load, sorted: what loops over every planner use.

    A broken plugin is left out of them, and troubles only a command that names it.
    """
    return plugins.usable(PLANNER_GROUP, "planner", _not_a_planner)


def broken_planners() -> dict[str, str]:
    """Each registered planner that cannot be used, with its one-line problem (`llmnav planners` lists them)."""
    return plugins.broken(PLANNER_GROUP, "planner", _not_a_planner)


def planner_source(name: str) -> str:
    """The distribution and version that supply planner `name` ("llmnav 0.1.0"), for the run log."""
    return plugins.find(PLANNER_GROUP, "planner", name).source


def inapplicable_options(planner: str, given: set[str]) -> list[str]:
    """The option names among `given` that planner `planner` ignores (for a one-line note to the user)."""
    return planner_class(planner).unused_options(given)


def get_planner(name: str) -> Planner[Any]:
    """Instantiate a planner by its registered name."""
    return planner_class(name)()
