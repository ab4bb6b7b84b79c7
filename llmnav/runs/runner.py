"""The episode runner: one scenario + task + start pose + planner + backend + options → one run folder.

`run_episode` builds the world, resolves the task, opens the run folder and its `RunLog` (first line: the
full configuration), creates the backend when the planner needs one, runs the planner, logs the `end`
event, and writes `summary.json` and (unless `plots` is off) `trajectory.png`. Whatever happens inside the
planner, the log ends with an `end` event: a bug ends the episode "aborted" and is re-raised after the log
is closed; an `LlmnavError` (model failure, replay divergence) just ends it "aborted" with its one-line
message, and is re-raised too when it is bad input (a server that takes no images), so the command exits 2.
"""

from __future__ import annotations

import hashlib
import math
import platform
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pydantic import BaseModel, ConfigDict, Field, field_validator

import llmnav
from llmnav.backends.base import backend_source, get_backend, request_modality
from llmnav.backends.cache import ReplyCache
from llmnav.backends.policy import PolicyBackend
from llmnav.backends.prices import load_prices
from llmnav.core.robot_specs import ROBOT_SPECS
from llmnav.errors import (
    BadInputError,
    LlmnavError,
    ModelError,
    ReplayDivergenceError,
    SensorFailure,
    one_line,
    redact_userinfo,
)
from llmnav.planners import prompting
from llmnav.planners.base import (
    DriveOptions,
    EpisodeContext,
    EpisodeOutcome,
    GroundTruth,
    Information,
    NullView,
    RedactedView,
    View,
    as_planner_options,
    drive_options,
    get_planner,
    planner_source,
)
from llmnav.reporting.trajectory import plot_record
from llmnav.reporting.velocity import PROFILE_FILE, plot_velocity_profile
from llmnav.runs.runlog import RunLog, read_run
from llmnav.scoring.metrics import aborted_by_infrastructure, summarize_run
from llmnav.world.knowledge import resolve_information, scenario_view
from llmnav.world.scenario import check_added_obstacles, resolve_scenario_path
from llmnav.world.tasks import SEQUENCE_JOIN, resolve_task

if TYPE_CHECKING:
    from collections.abc import Callable

    from llmnav.backends.base import Backend
    from llmnav.backends.prices import PriceTable
    from llmnav.core.geometry import Pose2D
    from llmnav.planners.base import Planner
    from llmnav.runs.runlog import RunRecord
    from llmnav.sim.world import World
    from llmnav.world.scenario import Scenario, Task

TRAJECTORY_FILE = "trajectory.png"
# Errors that end an episode "aborted" without saying anything about navigation: no answer came.
BACKEND_FAILURES = (ModelError, ReplayDivergenceError, BadInputError)
_ADDED_OBSTACLE_SIZE_M = 0.5  # [m] the box World.add_obstacle drops by default


class EpisodeSpec(BaseModel):
    """Everything that defines one episode."""

    model_config = ConfigDict(extra="forbid")

    scenario: str  # bundled name or path; "" lets the task pick it (see llmnav.world.tasks)
    task_id: str | None = None
    task_text: str | None = None  # several legs joined by llmnav.world.tasks.SEQUENCE_JOIN form a sequence
    start_pose: int = 1  # 1-based index into the task's start poses
    options: DriveOptions = Field(default_factory=drive_options)  # the planner's own Options model
    backend: str = "local"
    out_dir: Path
    quiet: bool = True
    plots: bool = True  # write trajectory.png (ablations turn it off: it costs more than a short episode)
    condition: str | None = None  # an ablation's hash of the episode's full condition, logged in the config
    # [Hz] also log full scans, odometry and velocity at this rate (llmnav.ros.record)
    record_hz: float | None = Field(default=None, gt=0, le=50)
    foxglove_port: int | None = Field(default=None, ge=0, le=65535)  # live view on 127.0.0.1 (0: any free port)
    # not part of the condition: where HTTP replies are cached (`--cache`), which prices cost the run
    cache_dir: Path | None = None
    prices: Path | None = None  # a price table (`--prices`); None: $LLMNAV_PRICES, else the bundled one

    @field_validator("options", mode="before")
    @classmethod
    def _planner_options(cls, options: Any) -> Any:
        # a mapping is the planner's own options; a bare DriveOptions takes the planner's defaults for the rest
        if isinstance(options, dict):
            return drive_options(**options)
        return as_planner_options(options) if isinstance(options, DriveOptions) else options


def _package_version(name: str) -> str | None:
    try:
        return version(name)
    except PackageNotFoundError:
        return None


def _file_hash(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()[:16]


def prompt_hashes(planner: Planner, options: DriveOptions) -> dict[str, str]:
    """Hashes of the prompt templates a planner renders (its `templates` hook)."""
    return {name: prompting.template_hash(name, planner.prompt_package) for name in planner.templates(options)}


def task_record(task: Task) -> dict[str, Any]:
    """The task as the config line records it."""
    return {
        "id": task.id,
        "text": task.text,
        "kind": task.kind,
        "difficulty": task.difficulty,
        "targets": [t.model_dump(mode="json", exclude_none=True) for t in task.targets],
        "wording": task.wording,
    }


def build_config(
    spec: EpisodeSpec,
    scenario: Scenario,
    scenario_path: Path,
    task: Task,
    start: Pose2D,
    prompts: dict[str, str],
    backend: Backend | None,
    information: str | None = None,
) -> dict[str, Any]:
    """The run's first log line: enough to reproduce the episode and to group it in tables."""
    camera = (spec.options.image_width, spec.options.image_height) if "image" in spec.options.sensing else None
    return {
        "versions": {
            "llmnav": llmnav.__version__,
            "python": platform.python_version(),
            "pybullet": _package_version("pybullet"),
            "numpy": _package_version("numpy"),
        },
        "scenario": scenario.name,
        "scenario_file": str(scenario_path),
        "scenario_hash": _file_hash(scenario_path),
        "task": task_record(task),
        "start_pose_index": spec.start_pose,
        "start_pose": start.as_list(),
        "planner": spec.options.planner,
        # which distribution supplied the code that ran: a plugin is named, never taken for a built-in
        "sources": {
            "planner": planner_source(spec.options.planner),
            "backend": backend_source(backend) if backend is not None else None,
        },
        "information": information,
        "answers": answers_information(backend),
        "backend": redact_userinfo(backend.spec) if backend is not None else None,
        # who bills the model's calls (llmnav.backends.prices): {"free": why} or {"provider", "model"}
        "billing": backend.billing() if backend is not None else None,
        # what the requests carried (replay asks the same): {"modality": "text" | "multimodal", "attachments"}
        **(request_modality(backend, camera) if backend is not None else {"modality": None, "attachments": []}),
        "options": spec.options.model_dump(mode="json"),
        "seed": spec.options.seed,
        "prompt_hashes": prompts,
        **({"condition_hash": spec.condition} if spec.condition else {}),
    }


def oracle_backend(backend: Backend | None) -> PolicyBackend | None:
    """`backend` when it answers from the planner's answer key (`policy:oracle`), else None."""
    return backend if isinstance(backend, PolicyBackend) and backend.wants_answer_key else None


def answers_information(backend: Backend | None) -> str | None:
    """What the answerer knew: "oracle" (ground truth, `policy:oracle`), "request" (only what it was sent)."""
    if backend is None:
        return None
    return "oracle" if oracle_backend(backend) is not None else "request"


def _world_configs(scenario: Scenario, options: DriveOptions) -> dict[str, Any]:
    """LiDAR and camera configs: the scenario's defaults, the camera at the requested resolution."""
    camera = scenario.sensors.camera.model_copy(update={"width": options.image_width, "height": options.image_height})
    return {"lidar": scenario.sensors.lidar, "camera": camera}


def _check_obstacles(scenario: Scenario, start: Pose2D, options: DriveOptions) -> None:
    """Added obstacles inside the world and clear of the robot's start (bad input, before any folder)."""
    robot = ROBOT_SPECS.get(scenario.robot)
    clearance = (robot.radius_m if robot else 0.3) + _ADDED_OBSTACLE_SIZE_M * math.sqrt(0.5)
    check_added_obstacles(scenario, (start.x, start.y), options.obstacles, clearance)
    # Boxes that appear later only have to lie inside the world: they wait until the robot is clear.
    check_added_obstacles(scenario, (start.x, start.y), [(x, y) for x, y, _t in options.appearing], 0.0)


def run_episode(
    spec: EpisodeSpec,
    *,
    view: View | None = None,
    backend_obj: Backend | None = None,
    planner_obj: Planner[Any] | None = None,
    later: list[Callable[[], None]] | None = None,
) -> dict[str, Any]:
    """Run one episode and return its summary (also written to `summary.json`).

    `planner_obj`: an instance of the planner `spec.options.planner` names (a probe; see llmnav.testing).
    `later`: when given, the figures (trajectory.png, the planner's own) are not drawn before returning;
    a call that draws them and notes them in the returned summary is appended to it instead, so a command
    can show the result first. The summary names the trajectory's path already. A run that crashed
    draws its figures at once, as without `later`.
    """
    texts = spec.task_text.split(SEQUENCE_JOIN) if spec.task_text else None
    resolved = resolve_task(spec.scenario or None, texts, spec.task_id, spec.start_pose)
    scenario, task = resolved.scenario, resolved.task
    start = resolved.start.pose()
    _check_obstacles(scenario, start, spec.options)
    planner = planner_obj if planner_obj is not None else get_planner(spec.options.planner)
    prompts = prompt_hashes(planner, spec.options)  # an unknown --prompt fails here, before anything loads
    check_scenario = getattr(planner, "check_scenario", None)  # a planner that cannot run here: bad input
    if check_scenario is not None:
        check_scenario(scenario)
    information = resolve_information(spec.options.planner, scenario, spec.options.information)

    # Backend before the run folder: a missing key or engine is bad input and leaves nothing behind.
    backend = backend_obj
    owns_backend = False
    if backend is None and planner.requires_backend(spec.options):
        backend = get_backend(spec.backend)
        owns_backend = True
    if backend is not None and spec.options.drop_images:
        backend.drop_images = True

    prices = load_prices(spec.prices)  # a bad price file is bad input before any folder exists
    if backend is not None and spec.cache_dir is not None:
        backend.use_cache(ReplyCache(spec.cache_dir))
    if backend is not None:
        try:
            planner.check_backend(backend, spec.options)
            if oracle_backend(backend) is not None and not planner.offers_oracle_answers():
                raise BadInputError(f"the {spec.options.planner} planner offers no oracle answers ({backend.spec})")
        except BaseException:
            if owns_backend:
                backend.close()
            raise
    try:
        # deferred: pybullet prints a banner on stderr, which bad input above must not precede
        from llmnav.sim.world import World

        with World(scenario, seed=spec.options.seed, **_world_configs(scenario, spec.options)) as world:
            world.reset(start, seed=spec.options.seed)
            for x, y in spec.options.obstacles:
                world.add_obstacle(x, y)
            for x, y, at_s in spec.options.appearing:
                world.schedule_obstacle(x, y, at_s)
            # A planner that paces its own control loop is not paced again by the physics steps.
            world.realtime = spec.options.realtime and not planner.paces_itself
            config = build_config(
                spec,
                scenario,
                resolve_scenario_path(spec.scenario or scenario.name),
                task,
                start,
                prompts,
                backend,
                information,
            )
            # the key and URL credentials the backend holds are never logged or shown, even when echoed
            live = None
            if spec.foxglove_port is not None:  # the export's topics while it drives; a busy port fails here
                # deferred: the live view brings numpy (about 0.1 s), only with foxglove_port
                from llmnav.ros.live import LiveView

                live = LiveView(spec.foxglove_port, spec.out_dir)
            try:
                with RunLog(spec.out_dir, config, secrets=getattr(backend, "secrets", ())) as log:
                    shown = RedactedView(view or NullView(), getattr(backend, "secrets", ()))
                    if live is not None:
                        log.listeners.append(live.on_event)
                    return _run_logged(
                        planner, world, scenario, task, backend, log, spec, shown, information, later, prices
                    )
            finally:
                if live is not None:
                    live.close()
    finally:
        if owns_backend and backend is not None:
            backend.close()


def _run_logged(
    planner: Planner,
    world: World,
    scenario: Scenario,
    task: Task,
    backend: Backend | None,
    log: RunLog,
    spec: EpisodeSpec,
    view: View,
    information: Information = "oracle",
    later: list[Callable[[], None]] | None = None,
    prices: PriceTable | None = None,
) -> dict[str, Any]:
    """Run the planner inside an open log; always end the log, summary and plot (or leave the plot to `later`).

    The planner gets the scenario as its information mode lets it see it (llmnav.world.knowledge); the
    summary is computed on the full scenario.
    """
    recorder = None
    if spec.record_hz is not None:
        # deferred: the recorder brings numpy (about 0.1 s), only with record_hz
        from llmnav.ros.record import Recorder

        recorder = Recorder(world, log, spec.record_hz, spec.options.seed)

    def on_pose(pose: Pose2D, t_sim: float) -> None:
        log.sim_time = t_sim
        log.event("pose", pose=pose.as_list())
        if recorder is not None:
            recorder.sample(t_sim)

    world.motion.on_pose = on_pose
    log.sim_time = world.sim_time
    log.event("pose", pose=world.robot.pose().as_list())
    if recorder is not None:
        recorder.log_map(scenario)
        recorder.sample(world.sim_time)
    # deferred: the guarded layer brings numpy and pybullet (about 0.2 s), only when an episode runs
    from llmnav.guard.view import PlannerWorld

    known = scenario_view(scenario, information, knows_map=planner.knows_map)
    ctx = EpisodeContext(known, task, PlannerWorld(world, log), backend, log, spec.options, view, information)
    _attach_answer_key(planner, world, scenario, task, backend, spec.options)
    crash: BaseException | None = None
    try:
        outcome = planner.run(ctx)
    except LlmnavError as err:
        # `failure` tells a resume what to run again: the model or server failing (not a navigation result)
        # (or a range sensor the collision monitor relies on: an outage of the robot, not of the model)
        failure = (
            "backend" if isinstance(err, BACKEND_FAILURES) else "sensor" if isinstance(err, SensorFailure) else "model"
        )
        outcome = EpisodeOutcome("aborted", one_line(err), metrics={"failure": failure})
        if isinstance(err, BadInputError):  # e.g. a server that takes no images: exit 2 with its hint
            crash = err
    except BaseException as err:  # a bug or Ctrl-C: keep the log valid, then let it propagate
        crash = err
        reason = (
            "interrupted" if isinstance(err, KeyboardInterrupt) else f"crash: {type(err).__name__}: {one_line(err)}"
        )
        outcome = EpisodeOutcome("aborted", reason)
    finally:
        world.motion.on_pose = None
        oracle = oracle_backend(backend)
        if oracle is not None:
            oracle.attach_answer_key(None)
    log.sim_time = world.sim_time
    log.event("pose", pose=world.robot.pose().as_list())
    log.event(
        "end",
        outcome=outcome.outcome,
        reason=outcome.reason,
        iterations=outcome.iterations,
        metrics=outcome.metrics,
    )

    log.check_written()  # a full disk: one error, no summary of a log that stops early
    record = read_run(log.run_dir)
    if crash is None:
        outcome.metrics = {**outcome.metrics, **planner.summarize(record, scenario, task)}
    summary = summarize_run(record, scenario, outcome, prices=prices)
    summary["information"] = information
    summary["answers"] = answers_information(backend)
    summary["run_dir"] = str(log.run_dir)
    log.write_summary(summary)
    if not spec.plots:
        summary["trajectory"] = None
    elif later is not None and crash is None:
        summary["trajectory"] = str(log.run_dir / TRAJECTORY_FILE)

        def draw() -> None:
            _plot(record, scenario, task, log.run_dir, summary)
            _planner_figures(planner, record, log.run_dir, summary)

        later.append(draw)
    else:
        _plot(record, scenario, task, log.run_dir, summary)
        _planner_figures(planner, record, log.run_dir, summary)
    if crash is not None:
        raise crash
    return summary


def _attach_answer_key(
    planner: Planner, world: World, scenario: Scenario, task: Task, backend: Backend | None, options: DriveOptions
) -> None:
    """Hand `policy:oracle` the planner's answer key, built from ground truth the planner's decisions never see."""
    oracle = oracle_backend(backend)
    if oracle is None:
        return
    # deferred: the oracle's map brings numpy (about 0.1 s), only with an oracle backend
    from llmnav.mapping.targets import with_added_obstacles

    truth = GroundTruth(
        with_added_obstacles(scenario, options.obstacles), task, world.robot.pose, lambda: world.sim_time
    )
    oracle.attach_answer_key(planner.oracle_answers(truth, options))


def _velocity_profile(run_dir: Path) -> Path | None:
    return plot_velocity_profile(run_dir, run_dir / PROFILE_FILE)


# The standard figures a planner may ask for by kind (`Planner.figure_kinds`): each draws from the run folder.
FIGURES: dict[str, Callable[[Path], Path | None]] = {
    "velocity_profile": _velocity_profile,  # commanded velocities over time, from the `cmd` records
}


def _planner_figures(planner: Planner, record: RunRecord, run_dir: Path, summary: dict[str, Any]) -> None:
    """The figures the planner asks for by kind, then its own (`figures` hook); a failure is noted, never fatal."""
    try:
        unknown = [kind for kind in planner.figure_kinds if kind not in FIGURES]
        if unknown:
            raise ValueError(f"unknown figure kind(s) {', '.join(unknown)} (known: {', '.join(sorted(FIGURES))})")
        drawn = [FIGURES[kind](run_dir) for kind in planner.figure_kinds]
        written = [path for path in drawn if path is not None] + planner.figures(record, run_dir)
    except Exception as err:  # noqa: BLE001 - as for the trajectory: the result matters more than a figure
        summary["figures_error"] = f"{type(err).__name__}: {one_line(err)}"
        return
    if written:
        summary["figures"] = [str(path) for path in written]


def _plot(record: RunRecord, scenario: Scenario, task: Task, run_dir: Path, summary: dict[str, Any]) -> None:
    """Write trajectory.png and note its path (or the error) in the summary."""
    # The figure is a convenience: a plotting failure must not cost the episode its result.
    try:
        summary["trajectory"] = str(plot_record(record, scenario, task, run_dir / TRAJECTORY_FILE))
    except Exception as err:  # noqa: BLE001
        summary["trajectory"] = None
        summary["trajectory_error"] = f"{type(err).__name__}: {one_line(err)}"


EXIT_SUCCESS, EXIT_TASK_FAILED, EXIT_MODEL_FAILED, EXIT_INFRASTRUCTURE = 0, 1, 3, 4  # 2 is bad input


def exit_code(summary: dict[str, Any]) -> int:
    """What `drive` and `plan` exit with, so scripts can tell the cases apart.

    0 the task succeeded; 1 it was not achieved (completed far from the target, or failed); 3 the model
    failed (no valid action, every motion vetoed); 4 the backend or its server failed (no answer came).
    """
    if aborted_by_infrastructure(summary):
        return EXIT_INFRASTRUCTURE
    if summary.get("outcome") == "aborted":
        return EXIT_MODEL_FAILED
    return EXIT_SUCCESS if summary.get("success") else EXIT_TASK_FAILED
