"""The FSM's oracle answers: the velocity a perfect assistant would suggest, from ground truth.

Each assist request is the state line the FSM publishes in APPROACH (`stop 1.23 -0.10 45 -150`); the
answer is `[v, w]` in whole mm/s and mrad/s, inside the kinematic box the answer's schema states, so the
guard judges it against that box as it judges any model's.

The sign the line describes is found among the scenario's signs of its class from the true pose (the one
whose true distance is nearest the reported one). Its stop point is where e_pos is measured, `d_goal` in
front of the board (`sign_stop_point`, shared with the FSM's metric), and the FSM stops when the detected
distance to the board reaches `d_goal`; so the answer drives onto the board's normal and along it:

- w = sat(k_w * bearing error) toward a pursuit point on the normal line, `lookahead_m` ahead of the
  robot's projection onto it (never past the board): the lateral offset from the normal decays, and the
  robot reaches the `d_goal` circle at the stop point instead of wherever its line of sight met it;
- v = min(v_max, sqrt(2 accel_max (d_true - d_goal))): full speed, braking within the FSM's own rate
  limit to zero exactly at `d_goal` on the true distance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

from llmnav.core.geometry import wrap_angle
from llmnav.planners.base import GeneratedAnswers

if TYPE_CHECKING:
    from llmnav.core.chat import ChatRequest
    from llmnav.planners.base import GroundTruth
    from llmnav.planners.fsm.control import FsmConfig
    from llmnav.world.scenario import LabelledObject, Scenario


def sign_stop_point(scenario: Scenario, obj: LabelledObject, d_goal: float) -> tuple[float, float]:
    """Where the FSM should stop for `obj`: `d_goal` in front of it (the p_target of e_pos).

    A sign's board is thin along one axis; its front is the side of that axis with free space.
    A target with an explicit goal point (or without a size) is used as it is.
    """
    if obj.goal is not None or obj.size is None:
        return obj.goal_point
    thin_yaw = obj.yaw + (math.pi / 2 if obj.size[0] >= obj.size[1] else 0.0)
    solids = scenario.solid_shapes()
    candidates = []
    for sign in (1.0, -1.0):
        x = obj.center[0] + sign * d_goal * math.cos(thin_yaw)
        y = obj.center[1] + sign * d_goal * math.sin(thin_yaw)
        clearance = min((shape.distance_to(x, y) for shape in solids), default=math.inf)
        candidates.append((clearance, (x, y)))
    return max(candidates)[1]


@dataclass
class FsmAnswerKey(GeneratedAnswers):
    """The `AnswerKey` of one FSM episode (see the module docstring)."""

    truth: GroundTruth
    cfg: FsmConfig
    lookahead_m: float = 0.3  # [m] pursuit point ahead on the normal: short enough to settle before d_goal

    def answer(self, request: ChatRequest) -> str:
        """`[v, w]` in whole mm/s and mrad/s for the true state now."""
        v, w = self.velocity(_state_line(request))
        return f"[{v},{w}]"

    def velocity(self, line: str) -> tuple[int, int]:
        """The answer to one state line, `[v, w]` in whole mm/s and mrad/s inside the box."""
        cfg = self.cfg
        parts = line.split()
        sign, reported = parts[0], float(parts[1])
        obj = self._sign(sign, reported)
        if obj is None:  # no such sign: leave the controller's own command as it is
            return round(float(parts[3])), round(float(parts[4]))
        pose = self.truth.pose()
        stop = sign_stop_point(self.truth.scenario, obj, cfg.d_goal)
        cx, cy = obj.goal_point
        # Unit normal from the board toward its stop point, and the robot's progress along it.
        nx, ny = stop[0] - cx, stop[1] - cy
        norm = math.hypot(nx, ny) or 1.0
        nx, ny = nx / norm, ny / norm
        along = (pose.x - cx) * nx + (pose.y - cy) * ny
        ahead = max(along - self.lookahead_m, 0.0)
        bearing = wrap_angle(math.atan2(cy + ny * ahead - pose.y, cx + nx * ahead - pose.x) - pose.yaw)
        w = _clip(cfg.k_w * bearing, cfg.w_max)
        remaining = max(pose.distance_to(cx, cy) - cfg.d_goal, 0.0)
        v = min(cfg.v_max, math.sqrt(2.0 * cfg.accel_max * remaining))
        # Whole milli-units rounded toward zero stay inside the schema's integer box.
        return max(math.floor(v * 1000), math.ceil(cfg.v_min * 1000)), int(w * 1000)

    def _sign(self, sign: str, reported_m: float) -> LabelledObject | None:
        """The scenario's `sign` board whose true distance is nearest the reported one."""
        pose = self.truth.pose()
        boards = [o for o in self.truth.scenario.objects if o.sign == sign]
        if not boards:
            return None
        return min(boards, key=lambda o: abs(pose.distance_to(*o.goal_point) - reported_m))


def _clip(value: float, limit: float) -> float:
    return min(max(value, -limit), limit)


def _state_line(request: ChatRequest) -> str:
    """The request's last user message: the FSM's state line."""
    return next(m.text for m in reversed(request.messages) if m.role == "user").strip()
