"""Driving one straight leg through the guarded motion layer, and the run log's `action` event.

Everything that drives to a point (the hybrid planner's options, the waypoint planner's segments, the
oracle's and the frontier baseline's paths) drives each leg with `drive_leg`, so a leg is judged and
recorded the same way whoever plans it:

1. check the leg with the layer's own check (`GuardedMotion.check_leg`: the round base's swept disc on
   the latest scans). A refused leg is not commanded: the layer records the refusal (a `guard` veto
   event naming the step) and the robot stays where it is;
2. otherwise command `go_to` through the layer. A veto it returns is a refused leg too, never success;
3. a leg the collision monitor stopped on the way is a refused leg as well, after the first rung of
   recovery: the robot backs off a little (`GuardedMotion.back_off`) so a new plan starts clear of it.
   The rest of the ladder (mark it on the map, plan around it, try again, give up when no way is left)
   is the planner's, which owns the map.

`Action` is the one form of the `action` event (what the view and the metrics read): every motion a
planner or baseline logs is built from the motion's result, so the fields mean the same everywhere.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

if TYPE_CHECKING:
    from llmnav.core.geometry import Pose2D
    from llmnav.guard.view import PlannerWorld
    from llmnav.sim.motion import MotionResult


@dataclass(frozen=True)
class Action:
    """One executed (or refused) motion, as the run log's `action` event records it."""

    step: int
    command: str  # GOTO, GO_TO, WAYPOINT, SCAN, ROTATE_LEFT, FRONT, COMPLETE, ...
    parameters: Any
    pose_before: Pose2D
    pose_after: Pose2D
    collided: bool = False
    collision_with: str | None = None
    stopped_reason: str | None = None  # see `MotionResult.stopped_reason`
    veto: str | None = None  # why the motion layer refused the motion (the robot did not move)
    distance_m: float | None = None  # [m] travelled (ground truth)
    rotated_deg: float | None = None  # [deg] turned (ground truth)
    duration_s: float | None = None  # [s] sim time
    option: str | None = None  # the menu entry the motion carried out (hybrid)
    index: int | None = None  # the waypoint's number in its plan (waypoints)

    @classmethod
    def of(cls, step: int, command: str, parameters: Any, result: MotionResult, **extra: Any) -> Action:
        """The action a motion's result describes."""
        return cls(
            step,
            command,
            parameters,
            result.start,
            result.end,
            collided=result.collided,
            collision_with=result.collision_with,
            stopped_reason=result.stopped_reason,
            veto=result.veto,
            distance_m=round(result.distance_m, 4),
            rotated_deg=round(math.degrees(result.rotated_rad), 3),
            duration_s=round(result.duration_s, 3),
            **extra,
        )

    def fields(self) -> dict[str, Any]:
        """The event's fields; unset optional ones are left out."""
        out: dict[str, Any] = {
            "step": self.step,
            "command": self.command,
            "parameters": self.parameters,
            "pose_before": self.pose_before.as_list(),
            "pose_after": self.pose_after.as_list(),
            "collided": self.collided,
            "collision_with": self.collision_with,
            "stopped_reason": self.stopped_reason,
        }
        if self.veto is not None:
            out |= {"vetoed": True, "veto": self.veto}
        optional = {
            "distance_m": self.distance_m,
            "rotated_deg": self.rotated_deg,
            "duration_s": self.duration_s,
            "option": self.option,
            "index": self.index,
        }
        return out | {k: v for k, v in optional.items() if v is not None}

    def log(self, sink: TimedSink) -> None:
        """Append the `action` event."""
        sink.event("action", **self.fields())


def _into(frame: Pose2D, seen_from: Pose2D, point: tuple[float, float]) -> tuple[float, float]:
    """A point [m] given in `seen_from`'s robot frame, in `frame`'s robot frame."""
    wx, wy = seen_from.point_at(math.atan2(point[1], point[0]), math.hypot(*point))
    dx, dy = wx - frame.x, wy - frame.y
    c, s = math.cos(frame.yaw), math.sin(frame.yaw)
    return (round(c * dx + s * dy, 3), round(-s * dx + c * dy, 3))


class TimedSink(Protocol):
    """The run log as a leg sees it: events stamped with the sim time it was last given."""

    sim_time: float | None

    def event(self, type_: str, **fields: Any) -> None:
        """Append one event."""
        ...


def drive_leg(
    world: PlannerWorld,
    x: float,
    y: float,
    *,
    step: int,
    log: TimedSink | None = None,
    command: str = "GO_TO",
    parameters: Any = None,
    index: int | None = None,
    **go_to_options: Any,
) -> MotionResult:
    """Drive the straight leg to (x, y) [m] (go_to's odometry frame) through the guarded motion layer.

    A refused leg comes back with `veto` set and `stopped_reason == "vetoed"`; the robot has not moved.
    With `log`, the leg is logged as one `Action` (`command`, `parameters` [x, y] unless given, the
    waypoint `index`); a planner that logs one action per decision instead passes none.
    """
    motion = world.motion
    verdict = motion.check_leg(x, y)
    if verdict.allowed:
        result = motion.go_to(x, y, **go_to_options)
    else:
        result = motion.refuse_leg(x, y, verdict, step=step)
    if result.stopped_reason == "monitor":
        # The first rung of recovery, for every planner alike: back away from what stopped the robot, so
        # the planner's next leg (around it, on a map that now holds it) starts clear of it. What blocked
        # it is then re-expressed in the robot's new frame (by odometry over the short reverse).
        stopped_at = world.robot.odom()
        back = motion.back_off()
        result.distance_m += back.distance_m
        result.end = back.end
        now = world.robot.odom()
        result.veto_points = tuple(_into(now, stopped_at, p) for p in result.veto_points)
        result.veto_hit = _into(now, stopped_at, result.veto_hit) if result.veto_hit is not None else None
    if log is not None:
        log.sim_time = world.sim_time
        shown = parameters if parameters is not None else [round(x, 3), round(y, 3)]
        Action.of(step, command, shown, result, index=index).log(log)
    return result
