"""The collision monitor on the real simulator: it judges every control step of every motion, from range
data alone, and stops the robot short of what the motion checks before it missed."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from llmnav.core.geometry import Pose2D
from llmnav.errors import SensorFailure
from llmnav.guard.legs import drive_leg
from llmnav.guard.view import PlannerWorld
from llmnav.sim.world import World
from llmnav.world.scenario import load_scenario, parse_scenario


class Log:
    """Collects events as the run log would."""

    def __init__(self) -> None:
        self.sim_time: float | None = 0.0
        self.events: list[tuple[str, dict[str, Any]]] = []

    def event(self, kind: str, **fields: Any) -> None:
        self.events.append((kind, fields))

    def of(self, kind: str) -> list[dict[str, Any]]:
        return [f for k, f in self.events if k == kind]


def _clearance_to_box(pose: Pose2D, radius: float, centre: tuple[float, float], size: tuple[float, float]) -> float:
    """[m] gap between a round base at `pose` and an axis-aligned box (worked out here, not by the monitor)."""
    dx = max(abs(pose.x - centre[0]) - size[0] / 2, 0.0)
    dy = max(abs(pose.y - centre[1]) - size[1] / 2, 0.0)
    return math.hypot(dx, dy) - radius


# --- a pallet below the LiDAR's plane ------------------------------------------------------------------


def test_a_leg_into_the_factory_pallet_is_refused_and_a_motion_past_the_check_is_stopped_by_the_low_scanner() -> None:
    factory = load_scenario("factory")
    pallet = next(o for o in factory.objects if o.id == "WP")  # 0.15 m high: the LiDAR (0.28 m) sees over it
    assert pallet.height < factory.sensors.lidar.mount_height_m or pallet.height < 0.28
    start = Pose2D(pallet.center[0], pallet.center[1] + 2.6, -math.pi / 2)  # north of it, facing it
    with World(factory, seed=0) as world:
        world.reset(start)
        log = Log()
        view = PlannerWorld(world, log)
        # The leg check sees the pallet through the low scanner: the robot does not move.
        refused = view.motion.go_to(pallet.center[0], pallet.center[1] + 0.5)
        assert refused.stopped_reason == "vetoed" and refused.distance_m == 0.0
        # A motion that no check judged first (the raw motion, which planners never hold) is still watched on
        # every control step: it ends short of the pallet, stopped by the low scanner.
        stopped = world.motion.drive(3.0)
        assert not stopped.collided and stopped.stopped_reason == "monitor"
        assert "low scanner" in (stopped.veto or "")
        gap = _clearance_to_box(world.robot.pose(), world.robot.spec.radius_m, pallet.center, pallet.size)
        assert 0.0 < gap < 0.15
        assert world.robot.contacts() == []
        # Without the monitor the same drive ends on the pallet: the test would catch a monitor that did nothing.
        world.motion.monitor = None
        world.reset(start)
        assert world.motion.drive(3.0).collision_with == "WP"


def test_a_monitor_stop_is_a_logged_veto_and_the_leg_backs_off() -> None:
    sc = parse_scenario(
        {
            "name": "appearing-box",
            "robot": "burger",
            "bounds": {"x": [-1, 6], "y": [-2, 2]},
            "default_start": {"x": 0.0, "y": 0.0},
        },
        "test",
    )
    with World(sc) as world:
        log = Log()
        view = PlannerWorld(world, log)
        world.reset(Pose2D(0.0, 0.0, 0.0))
        # The leg is clear when checked; a low box is dropped on it after the check, as a person would step in.
        verdict = view.motion.check_leg(4.0, 0.0)
        assert verdict.allowed
        box = world.add_obstacle(2.0, 0.0, size=0.4)
        assert box >= 0
        result = drive_leg(view, 4.0, 0.0, step=1)
        assert result.stopped_reason == "monitor" and not result.collided
        assert world.motion.collisions == 0
        veto = [g for g in log.of("guard") if g.get("outcome") == "veto"]
        assert veto and veto[0]["zone"] == "stop" and veto[0]["source"] in ("LiDAR", "low scanner")
        assert 0.0 <= veto[0]["distance_m"] < 0.1
        assert view.motion.vetoes == 1
        back = log.of("recovery")
        assert back and back[0]["behaviour"] == "back_off" and back[0]["travelled_m"] > 0.1
        # It stopped short of the box's west face (1.8 m) by its radius, and then backed away from it.
        assert world.robot.pose().x < 1.8 - world.robot.spec.radius_m - 0.1


# --- a square base turning beside a wall end ------------------------------------------------------------

SQUARE = {
    "name": "wall-end",
    "robot": "pr2-square",
    "bounds": {"x": [-3, 3], "y": [-3, 3]},
    # A wall ending just outside the square's side, inside the circle its corners sweep (radius 0.47 m).
    "walls": [{"id": "wall-end", "center": [0.22, 1.4], "size": [0.06, 2.0]}],
    # (Start poses in scenario files must clear the whole swept circle; the test puts the robot there itself.)
    "default_start": {"x": -2.0, "y": -2.0},
}


def test_a_turn_that_would_swing_a_corner_into_a_wall_end_is_stopped() -> None:
    sc = parse_scenario(SQUARE, "test")
    with World(sc) as world:
        start = Pose2D(0.0, 0.0, 0.0)
        world.reset(start)
        assert world.robot.contacts() == []  # the wall end (y from 0.4 m) clears the square's side (0.334 m)
        view = PlannerWorld(world, Log())
        result = view.motion.rotate(math.radians(40.0))
        assert result.stopped_reason == "monitor" and not result.collided
        assert world.robot.contacts() == []
        assert 0.0 < result.rotated_rad < math.radians(40.0)
        # The same turn without the monitor swings the corner into the wall end.
        world.motion.monitor = None
        world.reset(start)
        assert world.motion.rotate(math.radians(40.0)).collision_with == "wall-end"


def test_a_round_base_turns_freely_beside_the_same_wall_end() -> None:
    sc = parse_scenario(dict(SQUARE, robot="pr2", walls=[{"id": "w", "center": [0.22, 1.4], "size": [0.06, 2.0]}]), "t")
    with World(sc) as world:
        world.reset(Pose2D(0.0, 0.0, 0.0))
        view = PlannerWorld(world, Log())
        result = view.motion.rotate(math.radians(90.0))
        assert result.ok and result.stopped_reason is None


# --- odometry drift toward a door frame ----------------------------------------------------------------

DOOR = {
    "name": "door",
    "robot": "pr2",
    "bounds": {"x": [-3, 5], "y": [-3, 3]},
    # A wall at x = 2 with a doorway of the robot's width + 0.3 m (1.02 m) centred on y = 0.
    "walls": [
        {"id": "frame-south", "center": [2.0, -1.76], "size": [0.2, 2.5]},
        {"id": "frame-north", "center": [2.0, 1.76], "size": [0.2, 2.5]},
    ],
    "default_start": {"x": 0.0, "y": 0.0},
}


def test_a_leg_whose_odometry_drifted_into_a_door_frame_is_stopped_then_a_new_plan_goes_through() -> None:
    sc = parse_scenario(DOOR, "test")
    with World(sc) as world:
        log = Log()
        view = PlannerWorld(world, log)
        world.reset(Pose2D(0.0, 0.0, 0.0))
        # The robot believes it stands 0.45 m south of where it is (drift gathered over a long drive): the
        # leg to the doorway's far side, in its belief, runs in truth into the north door frame.
        world.robot._odom = Pose2D(0.0, -0.45, 0.0)
        result = drive_leg(view, 3.5, 0.0, step=1)
        assert not result.collided and world.motion.collisions == 0
        assert result.stopped_reason in ("vetoed", "monitor")
        # A new plan from a corrected pose (what a localizer gives) lines up with the doorway, then passes it.
        world.robot._odom = world.robot.pose()
        for leg, (x, y) in enumerate([(1.0, 0.0), (3.5, 0.0)], start=2):
            through = drive_leg(view, x, y, step=leg)
            assert through.ok and not through.collided, through.veto
        assert world.robot.pose().x > 3.0


# --- sources that fail ------------------------------------------------------------------------------------


def test_a_scanner_that_fails_mid_run_stops_the_run_as_an_outage() -> None:
    sc = parse_scenario(DOOR, "test")
    with World(sc) as world:
        view = PlannerWorld(world, Log())
        world.reset(Pose2D(0.0, 0.0, 0.0))
        lidar = world.low_lidar

        def broken(**_kw: Any) -> Any:
            scan = type(lidar).scan(lidar, max_range=1.0)
            scan.ranges = np.full(scan.ranges.shape, np.nan)
            return scan

        lidar.scan = broken  # type: ignore[method-assign]
        with pytest.raises(SensorFailure, match="low scanner"):
            view.motion.go_to(1.0, 0.0)


# --- boxes that appear mid-motion ---------------------------------------------------------------------


def test_a_scheduled_box_appears_on_time_mid_motion_and_never_on_the_robot() -> None:
    sc = parse_scenario(
        {"name": "open", "robot": "burger", "bounds": {"x": [-1, 6], "y": [-2, 2]}, "default_start": {"x": 0, "y": 0}},
        "test",
    )
    with World(sc) as world:
        log = Log()
        view = PlannerWorld(world, log)
        world.reset(Pose2D(0.0, 0.0, 0.0))
        world.schedule_obstacle(2.5, 0.0, at_s=2.0, size=0.4)  # on the leg, appearing 2 s into it
        world.schedule_obstacle(0.0, 0.0, at_s=0.5, size=0.4)  # where the robot stands then: it must wait
        assert view.motion.check_leg(4.5, 0.0).allowed  # nothing there when the leg is checked
        result = view.motion.go_to(4.5, 0.0)
        assert result.stopped_reason == "monitor" and not result.collided
        assert world.motion.collisions == 0
        assert sum(name.startswith("added:") for name in world.body_names.values()) == 2  # both dropped by now
        assert world.robot.pose().x < 2.3 - world.robot.spec.radius_m


def test_the_obstacle_flag_takes_a_time_and_refuses_a_bad_one(tmp_path) -> None:  # noqa: ANN001
    from typer.testing import CliRunner

    from llmnav.cli import app

    runner = CliRunner()
    bad = runner.invoke(
        app, ["drive", "--planner", "oracle", "--task-id", "A1", "--obstacle", "4,0@-1", "--out", str(tmp_path / "a")]
    )
    assert bad.exit_code == 2 and "must be >= 0 s" in bad.output
    assert not (tmp_path / "a").exists()
    outside = runner.invoke(
        app,
        [
            "drive",
            "--planner",
            "oracle",
            "--scenario",
            "corridor_a",
            "--task-id",
            "A1",
            "--obstacle",
            "99,0@3",
            "--out",
            str(tmp_path / "b"),
        ],
    )
    assert outside.exit_code == 2 and "outside the world" in outside.output


def test_a_sensor_outage_is_its_own_failure_cause() -> None:
    from llmnav.scoring.failures import failure_cause

    summary = {"success": False, "outcome": "aborted", "reason": "the low scanner failed", "collisions": 0}
    assert failure_cause({**summary, "planner_metrics": {"failure": "sensor"}}) == "outage"
    assert failure_cause({**summary, "planner_metrics": {"failure": "model"}}) == "model_failure"
