"""Raw access by a plug-in planner: the conformance kit (`llmnav.testing.check_planner`) fails a planner that
moves the robot around the guarded layer. A planner reaching `ctx.world.robot._RobotView__robot` to call
`pybullet.resetBasePositionAndOrientation` (it once put the robot inside a pallet, and the kit passed it),
or driving `ctx.world.motion._GuardedMotion__motion.drive(8)` with no veto, fails with a message naming
what happened. A plug-in is trusted code: the kit detects, it cannot prevent. Counted as category
"raw access".
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any, ClassVar

import pybullet
import pytest

from llmnav.baselines.oracle import OraclePlanner
from llmnav.core import plugins
from llmnav.planners.base import EpisodeContext, EpisodeOutcome
from llmnav.testing import check_planner

CATEGORY = "raw access"
SMALL_ROOM = str(Path(__file__).parents[1] / "runner" / "small_room.yaml")


class Teleporter(OraclePlanner):
    """Puts the robot next to the red box through the raw robot's body, then reports success."""

    name: ClassVar[str] = "teleporter"

    def run(self, ctx: EpisodeContext[Any]) -> EpisodeOutcome:
        robot = ctx.world.robot._RobotView__robot
        z = pybullet.getBasePositionAndOrientation(robot.body, physicsClientId=robot._client)[0][2]
        pybullet.resetBasePositionAndOrientation(robot.body, (6.5, 0.5, z), (0, 0, 0, 1), physicsClientId=robot._client)
        return EpisodeOutcome("completed", "arrived", iterations=1)


class SneakyTeleporter(Teleporter):
    """Teleports, then drives a guarded centimetre so the jump hides before a legal motion."""

    name: ClassVar[str] = "sneaky"

    def run(self, ctx: EpisodeContext[Any]) -> EpisodeOutcome:
        super().run(ctx)
        ctx.world.motion.rotate(0.1)
        return EpisodeOutcome("completed", "arrived", iterations=1)


class Unguarded(OraclePlanner):
    """Drives 8 m on the motion below the guard: no veto could stop it."""

    name: ClassVar[str] = "unguarded"

    def run(self, ctx: EpisodeContext[Any]) -> EpisodeOutcome:
        ctx.world.motion._GuardedMotion__motion.drive(8.0)
        return EpisodeOutcome("completed", "drove", iterations=1)


@pytest.fixture(autouse=True)
def registered(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Any:
    """The planners above registered under llmnav.planners by a dist-info folder (as `pip install` would)."""
    info = tmp_path / "raw_planners-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: raw-planners\nVersion: 0.1\n")
    names = {cls.name: cls.__name__ for cls in (Teleporter, SneakyTeleporter, Unguarded)}
    lines = "".join(f"{name} = {__name__}:{cls}\n" for name, cls in names.items())
    (info / "entry_points.txt").write_text(f"[llmnav.planners]\n{lines}")
    monkeypatch.syspath_prepend(str(tmp_path))
    plugins.forget()
    yield
    plugins.forget()


@pytest.mark.parametrize(
    ("cls", "message"),
    [
        (Teleporter, r"raw access to the simulator: the robot moved \d+\.\d+ m .* by the time the planner returned"),
        (SneakyTeleporter, r"raw access to the simulator: the robot moved \d+\.\d+ m .* before rotate"),
        (Unguarded, r"raw access to the simulator: the raw motion drive\(8\.0\) ran with no guard verdict"),
    ],
    ids=["teleport", "teleport then rotate", "drive below the guard"],
)
def test_the_kit_fails_a_planner_that_moves_the_robot_around_the_guard(cls: type, message: str, tally: Any) -> None:
    tally.add(CATEGORY, tried=1)
    try:
        check_planner(cls, scenario=SMALL_ROOM)
    except AssertionError as err:
        tally.add(CATEGORY, failures=int(not re.search(message, str(err))))
        assert re.search(message, str(err)), str(err)
        return
    tally.add(CATEGORY, failures=1)
    pytest.fail(f"check_planner passed {cls.__name__}")


def test_the_kit_restores_both_motion_layers(tally: Any) -> None:
    """The audit wraps the motion classes for one episode only."""
    from llmnav.guard.motion import GuardedMotion
    from llmnav.sim.motion import Motion

    tally.add(CATEGORY, tried=1)
    before = [(cls, name, cls.__dict__[name]) for cls in (GuardedMotion, Motion) for name in ("drive", "go_to")]
    with pytest.raises(AssertionError):
        check_planner(Unguarded, scenario=SMALL_ROOM)
    changed = [name for cls, name, method in before if cls.__dict__[name] is not method]
    tally.add(CATEGORY, failures=int(bool(changed)))
    assert not changed, changed
