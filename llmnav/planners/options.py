"""The options every episode has (`DriveOptions`), and the planner names registered as entry points.

`ChoiceOptions` adds the choice mode that planners choosing among options share.

A planner's own options extend `DriveOptions` in its own `Options` model (see `llmnav.planners.base`);
this module is below every planner and names none.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar, Literal, TypeVar, get_args, get_origin

from pydantic import BaseModel, ConfigDict, Field, field_validator

from llmnav.core import plugins
from llmnav.errors import BadInputError
from llmnav.planners import DEFAULT_PLANNER

if TYPE_CHECKING:
    from llmnav.backends.base import Backend

PLANNER_GROUP = "llmnav.planners"
# What a planner may know (see llmnav.world.knowledge): a published map, only its own sensors, or ground truth.
Information = Literal["map", "sensed", "oracle"]
# How a model-driven choice is made: scored option texts, generated answers, or scores where the backend can.
Decide = Literal["auto", "score", "generate"]


@dataclass(frozen=True)
class CliFlag:
    """A named command-line flag for one option key, declared on the options model that owns the key.

    `drive` takes one value (`--assist llm`, or `--self-check` for a `switch`); `ablate` takes the flag
    too when `sweep` says how: "factor" (a comma-separated list of values, each a condition) or "fixed"
    (one value for every episode). `llmnav.commands.common` builds both commands' flags from these, across
    the installed planners, so a plug-in adds a flag by declaring it.
    """

    flag: str  # "--assist"
    key: str  # the option key it sets ("assist")
    help: str  # drive's help text
    switch: bool = False  # an on/off flag (drive only) instead of one taking a value
    sweep: Literal["factor", "fixed"] | None = None  # how `ablate` takes it; None: drive only
    sweep_help: str | None = None  # ablate's help text (default: drive's)
    also: tuple[str, ...] = ()  # option fields a before-validator fills from `key`: their errors name this flag


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
    appearing: tuple[tuple[float, float, float], ...] = Field(
        default=(), description="[m, m, s] box obstacles dropped at X,Y when the simulation clock reaches T"
    )

    # Input keys beyond the fields that a before-validator maps onto fields (e.g. `ttl=auto`).
    input_aliases: ClassVar[frozenset[str]] = frozenset()
    # Named flags of its own keys for `drive` and `ablate` (any key stays reachable as `-o KEY=VALUE`)
    cli_flags: ClassVar[tuple[CliFlag, ...]] = ()

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
COMMON_OPTIONS: frozenset[str] = frozenset({"planner", "seed", "realtime", "obstacles", "appearing", "information"})
# The options of a model-driven planner that asks once per decision.
MODEL_OPTIONS: frozenset[str] = frozenset({"temperature", "max_tokens", "max_corrections"})


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


def planner_names() -> list[str]:
    """Every planner name registered under the `llmnav.planners` entry-point group, sorted.

    Broken ones too: `planners.base.usable_planner_names` leaves those out.
    """
    return sorted(plugins.registrations(PLANNER_GROUP))


def fallback_mark(requested: str, mode: str) -> dict[str, Any]:
    """The `condition` field of the event logging the decision mode: set when `auto` fell back to generation.

    `llmnav.scoring.metrics.condition_of` reads it, so tables show `decide=generate (fallback)`, never `decide=auto`
    over runs that generated (the backend could not score).
    """
    return {"condition": {"decide": "generate (fallback)"}} if requested == "auto" and mode == "generate" else {}


def decides_by_scores(options: ChoiceOptions, backend: Backend | None) -> bool:
    """Whether `decide` asks for scored choices with this backend (`auto`: if the backend can score)."""
    if options.decide == "generate" or backend is None:
        return False
    return options.decide == "score" or backend.can_score
