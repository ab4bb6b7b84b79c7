"""No planner can step around the guarded motion layer: every registered planner gets a context from which
no public path leads to the simulator's world, robot, raw motion or sensors."""

from __future__ import annotations

import dataclasses
from collections import deque
from pathlib import Path
from typing import Any

import pytest
from pydantic import BaseModel

from llmnav.guard.motion import GuardedMotion
from llmnav.planners.base import EpisodeContext, EpisodeOutcome, Planner, planner_class, planner_names
from llmnav.runs.runner import EpisodeSpec, run_episode
from llmnav.sim.motion import Motion
from llmnav.sim.robot import Robot
from llmnav.sim.sensors import Camera, Detector, Lidar
from llmnav.sim.world import World

SMALL = str(Path(__file__).parents[1] / "runner" / "small_room.yaml")
RAW = (World, Motion, Robot, Lidar, Camera, Detector)
BUILT_IN = {"stepwise", "waypoints", "fsm", "hybrid", "oracle", "frontier"}


def reachable(root: object, limit: int = 20000) -> list[tuple[str, object]]:
    """Every object reachable from `root` through public attributes, fields and container items."""
    seen: set[int] = set()
    out: list[tuple[str, object]] = []
    queue: deque[tuple[str, object]] = deque([("ctx", root)])
    while queue and len(out) < limit:
        path, obj = queue.popleft()
        if id(obj) in seen or isinstance(obj, str | bytes | int | float | bool | type(None) | Path):
            continue
        seen.add(id(obj))
        out.append((path, obj))
        children: list[tuple[str, Any]] = []
        if isinstance(obj, dict):
            children = [(f"{path}[{k!r}]", v) for k, v in obj.items()]
        elif isinstance(obj, list | tuple | set | frozenset):
            children = [(f"{path}[{i}]", v) for i, v in enumerate(obj)]
        elif type(obj).__module__.startswith("llmnav") or dataclasses.is_dataclass(obj):
            if isinstance(obj, BaseModel):  # pydantic data (scenario, options): its fields are all there is
                names = list(type(obj).model_fields)
            else:
                names = [f.name for f in dataclasses.fields(obj)] if dataclasses.is_dataclass(obj) else []
                names += [n for n in dir(obj) if not n.startswith("_")]
            for name in dict.fromkeys(names):
                try:
                    value = getattr(obj, name)
                except Exception:  # noqa: BLE001 - a property that needs state is not a handle
                    continue
                if callable(value) and not isinstance(value, type):
                    continue  # methods: what they return is checked by the episode tests
                children.append((f"{path}.{name}", value))
        queue.extend(children)
    return out


def test_every_builtin_planner_is_registered() -> None:
    assert BUILT_IN <= set(planner_names())


@pytest.mark.parametrize("name", sorted(BUILT_IN))
def test_the_context_a_planner_receives_reaches_no_raw_handle(tmp_path: Path, name: str, monkeypatch) -> None:
    seen: dict[str, EpisodeContext] = {}
    cls = planner_class(name)

    def capture(self: Planner, ctx: EpisodeContext) -> EpisodeOutcome:
        seen["ctx"] = ctx
        return EpisodeOutcome("completed", "captured")

    monkeypatch.setattr(cls, "run", capture)
    monkeypatch.setattr(cls, "requires_backend", lambda self, options: False)
    # The waypoint planner needs a scenario that publishes corridors (bad input otherwise).
    scenario, task = ("corridor_a", "A1") if name == "waypoints" else (SMALL, "T1")
    run_episode(
        EpisodeSpec(scenario=scenario, task_id=task, options={"planner": name}, out_dir=tmp_path / name, plots=False)
    )
    ctx = seen["ctx"]
    assert isinstance(ctx.world.motion, GuardedMotion)
    found = reachable(ctx)
    assert len(found) > 20  # the walk did go through the context
    raw = [(path, type(obj).__name__) for path, obj in found if isinstance(obj, RAW)]
    assert raw == []
    # The planner instance itself holds nothing of the world either.
    assert [p for p, obj in reachable(cls()) if isinstance(obj, RAW)] == []


def test_the_walk_would_find_a_raw_handle() -> None:
    # The checker itself can fail: a context-like object exposing the world is caught.
    @dataclasses.dataclass
    class Leaky:
        inner: dict[str, object]

    sentinel = object.__new__(World)
    leaks = [p for p, obj in reachable(Leaky({"w": [sentinel]})) if isinstance(obj, RAW)]
    assert leaks == ["ctx.inner['w'][0]"]
