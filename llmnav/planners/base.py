"""The planner interface, the episode context every planner receives, and the planner registry."""

from __future__ import annotations

import importlib
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Annotated, Any, ClassVar, Literal, Protocol

from pydantic import BaseModel, ConfigDict, Field

if TYPE_CHECKING:
    from llmnav.backends.base import Backend
    from llmnav.runlog import RunLog
    from llmnav.scenario import Scenario, Task
    from llmnav.sim.world import World

PlannerName = Literal["stepwise", "waypoints", "fsm", "hybrid", "oracle", "frontier"]
Outcome = Literal["completed", "failed", "aborted"]


class DriveOptions(BaseModel):
    """Every knob of one episode (the `llmnav drive` flags); logged in full in the run's config line."""

    model_config = ConfigDict(extra="forbid")

    planner: PlannerName = "hybrid"
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


@dataclass
class EpisodeContext:
    """Everything a planner may use during one episode."""

    scenario: Scenario
    task: Task
    world: World
    backend: Backend | None
    log: RunLog
    options: DriveOptions
    view: View = field(default_factory=NullView)


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

    def requires_backend(self, options: DriveOptions) -> bool:
        """Whether this episode needs a model (the runner creates no backend otherwise)."""
        return self.needs_backend

    @abstractmethod
    def run(self, ctx: EpisodeContext) -> EpisodeOutcome:
        """Drive one episode to its end; log every event through `ctx.log`; never print."""


_PLANNERS: dict[str, str] = {
    "stepwise": "llmnav.planners.stepwise:StepwisePlanner",
    "waypoints": "llmnav.planners.waypoints:WaypointPlanner",
    "fsm": "llmnav.planners.fsm:FsmPlanner",
    "hybrid": "llmnav.planners.hybrid:HybridPlanner",
    "oracle": "llmnav.baselines.oracle:OraclePlanner",
    "frontier": "llmnav.baselines.frontier:FrontierPlanner",
}


def get_planner(name: str) -> Planner:
    """Instantiate a planner by name (imported lazily: each pulls only what it needs)."""
    module_name, _, class_name = _PLANNERS[name].partition(":")
    cls = getattr(importlib.import_module(module_name), class_name)
    planner: Planner = cls()
    return planner
