"""What an LLM planner sees and how it talks to the model, shared by every LLM planner.

`observe` reads the robot's sensors according to `--sensing` (lidar, image, detections), logs one
`observation` event (the image stored beside the log, referenced by hash) and returns an `Observation`
whose `message` is the user turn for the model. The LiDAR is always scanned, even when the model is not
shown it: the safety veto works on the scan, never on what the model was told.

`call_model` is the one road to a backend: it logs an `llm_call` event with the request and the reply (or
the error) so that every planner's calls look the same in logs and replay identically. `call_scorer` is
its twin for scoring requests (log-probabilities of given continuations): the same event, with the
purpose `score`, the continuations in the request and the scores in the reply.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

from llmnav.backends.local import beside_simulation
from llmnav.core.chat import ChatRequest, ChatResult, Image, Message, ScoreRequest, ScoreResult
from llmnav.errors import LlmnavError, ModelError, one_line

if TYPE_CHECKING:
    from llmnav.backends.base import Backend
    from llmnav.core.geometry import Pose2D
    from llmnav.guard.view import PlannerWorld
    from llmnav.planners.options import DriveOptions
    from llmnav.runs.runlog import RunLog
    from llmnav.sensing.perception import LidarSummary
    from llmnav.sim.sensors import Detection, LidarScan


@dataclass
class Observation:
    """One reading of the sensors at a decision point."""

    step: int
    odom: Pose2D
    scan: LidarScan  # always taken: the veto needs it
    front_m: float | None  # [m] straight-ahead distance of the LiDAR summary
    lidar_text: str | None  # sector summary shown to the model (None when lidar is not sensed)
    image: Image | None = None
    detections: list[Detection] = field(default_factory=list)
    detections_text: str | None = None

    def text(self) -> str:
        """The observation as model-facing text (the image travels beside it)."""
        parts = [t for t in (self.lidar_text, self.detections_text) if t is not None]
        if self.image is not None:
            parts.append("Camera: the attached image is the current front camera view.")
        return "\n\n".join(parts) if parts else "No sensor data."

    def message(self, preface: str = "") -> Message:
        """The user turn carrying this observation, optionally after a preface (the task)."""
        body = self.text()
        text = f"{preface}\n\n{body}" if preface else body
        return Message("user", text, (self.image,) if self.image is not None else ())


def lidar_summary(scan: LidarScan, options: DriveOptions) -> LidarSummary:
    """The scan's front distance and sectors, per `--lidar-sectors` and `--lidar-fov`."""
    # deferred: perception brings numpy (about 0.1 s), only when the robot observes
    from llmnav.sensing.perception import summarize_scan

    return summarize_scan(scan, sectors=options.lidar_sectors, fov_deg=options.lidar_fov_deg)


def lidar_text(scan: LidarScan, options: DriveOptions) -> tuple[float | None, str]:
    """Front distance [m] and the compact sector line, per `--lidar-sectors` and `--lidar-fov`."""
    summary = lidar_summary(scan, options)
    return summary.front_m, compact_lidar_line(summary)


def sectors_log(summary: LidarSummary) -> list[dict[str, Any]]:
    """The sectors as logged: span [deg], rays, closest reading [m] and its angle [deg] (None: none in range)."""

    def number(value: float | None) -> float | None:
        return None if value is None or not math.isfinite(value) else round(value, 3)

    return [
        {
            "start_deg": round(s.start_deg, 2),
            "end_deg": round(s.end_deg, 2),
            "rays": s.rays,
            "closest_m": number(s.min_m),
            "angle_deg": number(s.min_angle_deg),
        }
        for s in summary.sectors
    ]


def compact_lidar_line(summary: LidarSummary) -> str:
    """One line per decision: `LiDAR front 2.3 m; closest m@deg per sector, left to right: 2.3@+40 inf ...`.

    This text is new to the model at every decision and is paid for in prompt tokens (digits are read
    one by one), so it carries only what changes: distances to 0.1 m (decisions move 0.5 m or more; the
    veto checks the real scan) and whole degrees. What does not change — the sectors' spans, the units,
    what `inf` means — is explained once in the system prompt. Sectors no ray covers say `n/a`.
    """

    def metres(value: float | None) -> str:
        if value is None:
            return "n/a"
        return "inf" if math.isinf(value) else f"{value:.1f}"

    cells = []
    for sector in summary.sectors:
        if sector.rays == 0:
            cells.append("n/a")
        elif sector.min_angle_deg is None:
            cells.append("inf")
        else:
            cells.append(f"{metres(sector.min_m)}@{sector.min_angle_deg:+.0f}")
    return f"LiDAR front {metres(summary.front_m)} m; closest m@deg per sector, left to right: {' '.join(cells)}"


def observe(
    world: PlannerWorld, options: DriveOptions, log: RunLog, step: int, *, image_needed: bool = True
) -> Observation:
    """Read the sensors `options.sensing` asks for, log the `observation` event, return it.

    `image_needed=False`: the caller sends the model no image (a text-only backend), so the camera frame,
    the costliest reading, is not rendered, and the observation has none.
    """
    # deferred: perception brings numpy (about 0.1 s), only when the robot observes
    from llmnav.sensing.perception import detections_text

    sensing = set(options.sensing)
    scan = world.lidar.scan()
    summary = lidar_summary(scan, options)
    front, sectors = summary.front_m, compact_lidar_line(summary)
    image = None
    if "image" in sensing and image_needed:
        image = world.camera.capture().image()
    detections: list[Detection] = []
    det_text = None
    if "detections" in sensing:
        detections = world.detector.detect()
        det_text = detections_text(detections)
    obs = Observation(
        step=step,
        odom=world.robot.odom(),
        scan=scan,
        front_m=front,
        lidar_text=sectors if "lidar" in sensing else None,
        image=image,
        detections=detections,
        detections_text=det_text,
    )
    log.event(
        "observation",
        step=step,
        pose=world.robot.pose().as_list(),  # the true pose, for scoring and the viewer only: the planner gets none
        odom=obs.odom.as_list(),
        lidar_front_m=None if front is None else round(front, 4),
        lidar_text=sectors,
        lidar_sectors=sectors_log(summary),
        lidar_range_m=scan.range_max,
        detections=[_detection_log(d) for d in detections],
        image=log.image(image) if image is not None else None,
    )
    return obs


def _detection_log(det: Detection) -> dict[str, Any]:
    return {
        "object_id": det.object_id,
        "label": det.label,
        "bearing_deg": round(det.bearing_deg, 2),
        "distance_m": round(det.distance_m, 3),
        "pixel_fraction": round(det.pixel_fraction, 4),
        "offset": round(det.offset, 3),
    }


class ModelLine(Protocol):
    """What a model call needs of an episode (`llmnav.planners.base.EpisodeContext` is one)."""

    @property
    def backend(self) -> Backend | None:
        """The model the episode asks, if any."""
        ...

    @property
    def log(self) -> RunLog:
        """Where the call is logged."""
        ...

    @property
    def options(self) -> DriveOptions:
        """The planner's options (its name, and whether the simulation runs beside the call)."""
        ...


def call_model(ctx: ModelLine, request: ChatRequest, purpose: str, step: int | None) -> ChatResult:
    """Send a request through `ctx.backend`, logging an `llm_call` event with the reply or the error.

    A backend failure (ModelError, ReplayDivergenceError, ...) is logged with its one-line message and
    re-raised, so the runner ends the episode "aborted" with that reason.
    """
    if ctx.backend is None:
        raise LlmnavError(f"planner '{ctx.options.planner}' called a model but no backend is configured")
    for message in request.messages:  # store every image the request refers to (cheap when already stored)
        for img in message.images:
            ctx.log.image(img)

    try:
        with beside_simulation(ctx.options.realtime):
            result = ctx.backend.chat(request)
    except LlmnavError as err:
        ctx.log.event("llm_call", **llm_call_fields(request, purpose, step, error=err, caching=ctx.backend.caching))
        raise
    ctx.log.event("llm_call", **llm_call_fields(request, purpose, step, result, caching=ctx.backend.caching))
    return result


def cache_state(meta: dict[str, Any], caching: bool) -> str:
    """What the reply cache did for a call: "hit", "miss" (asked the server), or "off" (no cache)."""
    state = meta.get("cache")
    if state in ("hit", "miss"):
        return str(state)
    return "miss" if caching else "off"


def _reply_log(log: dict[str, Any]) -> dict[str, Any]:
    """A reply's log form with the cache state lifted out of its meta (the event carries it, once)."""
    meta = log.get("meta")
    if isinstance(meta, dict) and "cache" in meta:
        log["meta"] = {k: v for k, v in meta.items() if k != "cache"}
    return log


def llm_call_fields(
    request: ChatRequest,
    purpose: str,
    step: int | None,
    result: ChatResult | None = None,
    error: BaseException | str | None = None,
    caching: bool = False,
) -> dict[str, Any]:
    """The fields of the `llm_call` event for a chat call: its reply, or its error when it failed.

    For a caller that made the call by other means than `call_model` (the FSM's model process) and logs
    it later, in the same form. `caching`: the backend has a reply cache (a failed call was a miss).
    """
    if result is None:
        return {
            "step": step,
            "purpose": purpose,
            "cache": cache_state({}, caching),
            "request": request.to_log(),
            "error": one_line(error or ""),
        }
    return {
        "step": step,
        "purpose": purpose,
        "cache": cache_state(result.meta, caching),
        "request": request.to_log(),
        "reply": _reply_log(result.to_log()),
        "new_prompt_tokens": new_prompt_tokens(result),
    }


def call_scorer(ctx: ModelLine, request: ScoreRequest, step: int | None) -> ScoreResult:
    """Score continuations through `ctx.backend`, logged as an `llm_call` event with purpose `score`.

    Failures are logged and re-raised like `call_model`'s; a reply with a different number of scores
    than continuations is a `ModelError` (never a silent misalignment of options and scores).
    """
    if ctx.backend is None:
        raise LlmnavError(f"planner '{ctx.options.planner}' asked for scores but no backend is configured")
    try:
        with beside_simulation(ctx.options.realtime):
            result = ctx.backend.score(request)
        if len(result.scores) != len(request.continuations):
            got, asked = len(result.scores), len(request.continuations)
            raise ModelError(f"{ctx.backend.spec} returned {got} scores for {asked} continuations")
    except LlmnavError as err:
        cache = cache_state({}, ctx.backend.caching)
        ctx.log.event(
            "llm_call", step=step, purpose="score", cache=cache, request=request.to_log(), error=one_line(err)
        )
        raise
    cache = cache_state(result.meta, ctx.backend.caching)
    reply = _reply_log(result.to_log())
    ctx.log.event("llm_call", step=step, purpose="score", cache=cache, request=request.to_log(), reply=reply)
    return result


def new_prompt_tokens(result: ChatResult) -> int | None:
    """Prompt tokens the model had to read for this call (not served from its prompt cache), if known.

    The local backend reports them directly; a backend that reports total and cached tokens gives the
    difference; one that reports only a total (no cache information) gives that total.
    """
    direct = result.meta.get("new_prompt_tokens")
    if isinstance(direct, int):
        return direct
    if result.prompt_tokens is None:
        return None
    cached = result.meta.get("cached_tokens")
    return result.prompt_tokens - cached if isinstance(cached, int) else result.prompt_tokens
