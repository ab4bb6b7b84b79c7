"""A conformance kit for plug-ins, in the spirit of Gymnasium's `check_env`.

- `check_planner(cls)` checks a planner registered under `cls.name`: its declarations (an `Options`
  model that forbids extras and gives a unit or meaning for every field of its own, information modes,
  grid factors), one short episode on a bundled scenario with a `policy:` backend, that nothing it is
  handed reaches the raw simulator, that every motion of the robot went through the guarded layer (no
  pose change between guarded motions, no call of the raw motion outside one), that its log holds
  well-formed events, and that its `summarize` and `figures` hooks survive a log cut short.

A plug-in is trusted code running in llmnav's process: it can reach anything Python can. The kit cannot
prevent raw access (a private attribute, `pybullet` itself); it detects its effects on the robot in the
probe episode and fails the planner for them.
- `check_backend(cls, arg)` checks a backend class: its spec round-trips, its options forbid extras, and
  bad input raises only llmnav's narrow error classes.

Each returns nothing and raises `AssertionError` naming the first thing that does not conform.
"""

from __future__ import annotations

import json
import math
import tempfile
import threading
from collections.abc import Callable, Iterator
from dataclasses import fields, is_dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from llmnav.backends.base import Backend, parse_spec
from llmnav.core.declarations import Declarations
from llmnav.errors import LlmnavError
from llmnav.runs.runlog import RUN_FILE, read_run

if TYPE_CHECKING:
    from llmnav.core.geometry import Pose2D
    from llmnav.planners.base import EpisodeContext, EpisodeOutcome, Planner

__all__ = ["check_backend", "check_planner"]

# Objects a planner must never hold: the simulator, the robot and the unguarded motion below the layer.
_RAW_MODULES = ("llmnav.sim.world", "llmnav.sim.robot", "llmnav.sim.motion", "pybullet")
# The motions of both layers: the guarded one planners hold, and the raw one below it.
_MOTIONS = ("drive", "rotate", "go_to", "velocity_tick")
# How far the robot may seem to move between guarded motions (a resting body settles by far less).
POSE_TOLERANCE_M = 0.01  # [m]
YAW_TOLERANCE_RAD = 0.02  # [rad]


def check_planner(
    cls: type[Planner[Any]],
    *,
    scenario: str = "corridor_a",
    task_id: str | None = None,
    backend: str = "policy:first",
    options: dict[str, Any] | None = None,
) -> None:
    """Check `cls` (registered under `cls.name`) against the planner contract; see the module docstring."""
    _check_declarations(cls)
    with tempfile.TemporaryDirectory(prefix="llmnav-check-") as folder:
        run_dir = Path(folder) / "run"
        summary, seen, bypasses = _run_probe(cls, scenario, task_id, backend, options or {}, run_dir)
        assert summary.get("outcome") in ("completed", "failed", "not_found", "aborted"), (
            f"outcome {summary.get('outcome')!r}"
        )
        raw = [path for path, kind in seen]
        assert not raw, f"{cls.name}: its context reaches the raw simulator: {', '.join(raw[:3])}"
        assert not bypasses, f"{cls.name}: raw access to the simulator: {'; '.join(bypasses[:3])}"
        _check_log(cls, run_dir)
        _check_hooks_on_a_cut_log(cls, run_dir, Path(folder), scenario)


def check_backend(cls: type[Backend], arg: str | None = None) -> None:
    """Check a backend class: spec round-trip, options that forbid extras, narrow errors on bad input."""
    assert issubclass(cls, Backend), f"{cls!r} is not a llmnav Backend"
    assert isinstance(getattr(cls, "name", None), str) and cls.name, f"{cls.__name__}: no `name`"
    backend = cls(arg)
    try:
        name, spec_arg = parse_spec(backend.spec)
        assert name == cls.name, f"{cls.name}: spec {backend.spec!r} names {name!r}"
        again = cls(spec_arg)
        try:
            assert again.spec == backend.spec, f"{cls.name}: spec {backend.spec!r} recreates {again.spec!r}"
        finally:
            again.close()
    finally:
        backend.close()
    for bad in ({"no_such_option": 1}, {"timeout_s": "soon"}):
        try:
            made = cls(arg, **bad)
        except LlmnavError:
            continue
        except Exception as err:  # noqa: BLE001 - the check is that nothing broader escapes
            raise AssertionError(f"{cls.name}: option {bad} raised {type(err).__name__}, not a llmnav error") from err
        made.close()
        raise AssertionError(f"{cls.name}: option {bad} was accepted (options must forbid extras)")


def _check_declarations(cls: type[Planner[Any]]) -> None:
    # deferred: the planner registry brings pydantic (about 0.1 s); `import llmnav.testing` stays light
    from llmnav.planners.base import DriveOptions, Planner, planner_class
    from llmnav.world.knowledge import INFORMATION_MODES

    assert issubclass(cls, Planner), f"{cls!r} is not a llmnav Planner"
    assert planner_class(cls.name) is cls, f"{cls.name}: the llmnav.planners entry point names another class"
    model = cls.Options
    assert issubclass(model, DriveOptions), f"{cls.name}: Options must extend DriveOptions"
    assert model.model_config.get("extra") == "forbid", f"{cls.name}: Options must forbid extra keys"
    for key in set(model.model_fields) - set(DriveOptions.model_fields):
        assert model.model_fields[key].description, f"{cls.name}: option {key!r} has no description (unit)"
    assert isinstance(cls.declares, Declarations), f"{cls.name}: `declares` is not a llmnav Declarations"
    names = [table.name for table in cls.declares.score_tables]
    assert len(set(names)) == len(names), f"{cls.name}: two score tables share a name"
    modes = cls.information_modes
    assert modes and set(modes) <= set(INFORMATION_MODES), f"{cls.name}: information modes {modes!r}"
    unknown = set(cls.grid_factors) - model.input_keys()
    assert not unknown, f"{cls.name}: grid factors {sorted(unknown)} are not its options"
    unknown = set(cls.options) - set(DriveOptions.model_fields)
    assert not unknown, f"{cls.name}: `options` names {sorted(unknown)}, not shared DriveOptions fields"


def _run_probe(
    cls: type[Planner[Any]], scenario: str, task_id: str | None, backend: str, options: dict[str, Any], run_dir: Path
) -> tuple[dict[str, Any], list[tuple[str, str]], list[str]]:
    """One short episode through the real runner: the context walked when the planner starts, its motions audited."""
    # deferred: the runner brings pydantic and yaml (about 0.15 s); `import llmnav.testing` stays light
    from llmnav.planners.base import drive_options
    from llmnav.runs.runner import EpisodeSpec, run_episode
    from llmnav.world.scenario import load_scenario

    seen: list[tuple[str, str]] = []
    bypasses: list[str] = []

    class Probe(cls):  # type: ignore[valid-type,misc]  # a subclass of the planner under test
        def run(self, ctx: EpisodeContext[Any]) -> EpisodeOutcome:
            seen.extend(_raw_handles(ctx))
            # The kit looks below the layer on purpose: the body's pose in the engine, not the copy planners read.
            robot = getattr(ctx.world.robot, "_RobotView__robot")  # noqa: B009 - a private name, reached on purpose
            with _MotionAudit(robot.engine_pose, bypasses):
                return super().run(ctx)

    task = task_id or load_scenario(scenario).tasks[0].id
    settings = {"max_iterations": 3, "seed": 0, **options}
    spec = EpisodeSpec(
        scenario=scenario, task_id=task, options=drive_options(cls.name, **settings), backend=backend,
        out_dir=run_dir, plots=False,
    )  # fmt: skip
    return run_episode(spec, planner_obj=Probe()), seen, bypasses


class _MotionAudit:
    """Watches a planner's episode for motion that bypassed the guarded layer, and lists each as a problem.

    Between two guarded motions the robot rests, so any pose change there was made by something else (a
    `pybullet.resetBasePositionAndOrientation` through a private handle); and the raw motion runs only
    inside a guarded one, so a call of it outside one had no guard verdict. Both layers' motion methods
    are wrapped for the episode (class attributes, restored on exit).
    """

    def __init__(self, pose: Callable[[], Pose2D], problems: list[str]) -> None:
        self._pose = pose
        self._last = pose()
        self.problems = problems
        self._depth = threading.local()  # per thread: (guarded calls, raw calls) in progress
        self._saved: list[tuple[type, str, Any]] = []

    def __enter__(self) -> _MotionAudit:
        # deferred: the guard and the simulator bring numpy and pybullet; `import llmnav.testing` stays light
        from llmnav.guard.motion import GuardedMotion
        from llmnav.sim.motion import Motion

        for name in _MOTIONS:
            self._wrap(GuardedMotion, name, guarded=True)
            self._wrap(Motion, name, guarded=False)
        return self

    def __exit__(self, *exc: object) -> None:
        for owner, name, original in reversed(self._saved):
            setattr(owner, name, original)
        self._saved.clear()
        if self._levels() == (0, 0):
            self._check_rest("by the time the planner returned")

    def _levels(self) -> tuple[int, int]:
        return getattr(self._depth, "guarded", 0), getattr(self._depth, "raw", 0)

    def _check_rest(self, when: str) -> None:
        here, last = self._pose(), self._last
        moved = math.hypot(here.x - last.x, here.y - last.y)
        turned = abs(math.remainder(here.yaw - last.yaw, math.tau))
        if moved > POSE_TOLERANCE_M or turned > YAW_TOLERANCE_RAD:
            self.problems.append(
                f"the robot moved {moved:.2f} m and turned {math.degrees(turned):.0f} deg with no guarded motion "
                f"({last.x:.2f}, {last.y:.2f}) -> ({here.x:.2f}, {here.y:.2f}), {when}"
            )
        self._last = here

    def _wrap(self, owner: type, name: str, *, guarded: bool) -> None:
        original = owner.__dict__[name]
        self._saved.append((owner, name, original))
        audit = self

        def watched(motion: Any, *args: Any, **kwargs: Any) -> Any:
            guarded_calls, raw_calls = audit._levels()
            if guarded and guarded_calls == 0:
                audit._check_rest(f"before {name}")
            if not guarded and guarded_calls == 0 and raw_calls == 0:
                shown = ", ".join([*map(repr, args), *(f"{k}={v!r}" for k, v in kwargs.items())])
                audit.problems.append(f"the raw motion {name}({shown}) ran with no guard verdict")
            key = "guarded" if guarded else "raw"
            setattr(audit._depth, key, getattr(audit._depth, key, 0) + 1)
            try:
                return original(motion, *args, **kwargs)
            finally:
                setattr(audit._depth, key, getattr(audit._depth, key) - 1)
                if guarded and audit._levels()[0] == 0:
                    audit._last = audit._pose()

        setattr(owner, name, watched)


def _raw_handles(root: Any, limit: int = 4000) -> Iterator[tuple[str, str]]:
    """Public attribute paths from `root` to an object of the raw simulator (breadth first, bounded)."""
    queue: list[tuple[str, Any]] = [("ctx", root)]
    visited: set[int] = set()
    while queue and len(visited) < limit:
        path, obj = queue.pop(0)
        if id(obj) in visited or obj is None or isinstance(obj, (str, bytes, int, float, bool, Path)):
            continue
        visited.add(id(obj))
        module = type(obj).__module__
        if module.startswith(_RAW_MODULES):
            yield path, module
            continue
        for name, child in _children(obj):
            queue.append((path + (name if name.startswith("[") else f".{name}"), child))


def _children(obj: Any) -> Iterator[tuple[str, Any]]:
    if isinstance(obj, dict):
        yield from ((f"[{k!r}]", v) for k, v in list(obj.items())[:50])
    elif isinstance(obj, (list, tuple, set, frozenset)):
        yield from ((f"[{i}]", v) for i, v in enumerate(list(obj)[:50]))
    elif is_dataclass(obj):
        yield from ((f.name, getattr(obj, f.name, None)) for f in fields(obj) if not f.name.startswith("_"))
    elif hasattr(obj, "__dict__") and not isinstance(obj, type):
        yield from ((k, v) for k, v in vars(obj).items() if not k.startswith("_"))


def _check_log(cls: type[Planner[Any]], run_dir: Path) -> None:
    record = read_run(run_dir)
    assert record.complete, f"{cls.name}: the run log has no end event"
    assert record.config.get("planner") == cls.name, f"{cls.name}: config names {record.config.get('planner')!r}"
    for number, event in enumerate(record.events, start=2):
        where = f"{cls.name}: event {number} ({event.get('type')})"
        assert isinstance(event.get("type"), str) and event["type"], f"{where}: no type"
        json.dumps(event, allow_nan=False)  # strict JSON: no NaN or Infinity in a log others read
        step = event.get("step")
        assert step is None or (isinstance(step, int) and step >= 0), f"{where}: step {step!r}"
        if event["type"] == "guard":
            assert isinstance(event.get("outcome"), str), f"{where}: a guard event without its outcome"
        if event["type"] == "action":
            assert isinstance(event.get("command", event.get("action")), str), f"{where}: no command"


def _check_hooks_on_a_cut_log(cls: type[Planner[Any]], run_dir: Path, folder: Path, scenario_name: str) -> None:
    """`summarize` and `figures` on the log of a run killed half-way: numbers or nothing, never a crash."""
    # deferred: the scenario loader brings pydantic and yaml (about 0.15 s); `import llmnav.testing` stays light
    from llmnav.world.scenario import load_scenario

    lines = (run_dir / RUN_FILE).read_text().splitlines()
    cut = folder / "cut"
    cut.mkdir()
    (cut / RUN_FILE).write_text("\n".join(lines[: max(2, len(lines) // 2)]) + "\n")
    record = read_run(cut)
    scenario = load_scenario(scenario_name)
    task = scenario.task(str(record.config["task"]["id"])) if record.config.get("task", {}).get("id") else None
    planner = cls()
    if task is not None:
        metrics = planner.summarize(record, scenario, task)
        assert isinstance(metrics, dict), f"{cls.name}: summarize returned {type(metrics).__name__}"
        for key, value in metrics.items():
            ok = (
                value is None
                or isinstance(value, (str, bool, int, list, dict))
                or (isinstance(value, float) and math.isfinite(value))
            )
            assert ok, f"{cls.name}: summarize gave {key}={value!r} on a cut log"
    figures = planner.figures(record, cut)
    assert all(Path(p).exists() for p in figures), f"{cls.name}: figures listed files it did not write"
