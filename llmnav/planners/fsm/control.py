"""The FSM's controller (source C): one pure 50 Hz step from its state and inputs to a new state and a command.

States SEARCH, APPROACH, ACT_LEFT, ACT_RIGHT, ACT_STOP. The baseline command is
v = sat(k_v (d - d_goal)), w = sat(k_w e_theta) with first-order rate limits; the fusion applies the
model's suggestion in force, v = (1 - alpha) v_base + alpha v_llm (the guard only lets through values
inside the admissible box, so no projection is needed), or smooths the baseline, v_t = (1 - beta) v_{t-1}
+ beta v_base. `tick` reads no clock, logs nothing and touches no simulator: what it decided to log
(state changes) comes back in its `Step`, for the loop to write once the command is out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal, NamedTuple

if TYPE_CHECKING:
    from llmnav.sim.sensors import Detection

State = Literal["SEARCH", "APPROACH", "ACT_LEFT", "ACT_RIGHT", "ACT_STOP"]
Assist = Literal["none", "ema", "llm"]
_ACT_ON_SIGN: dict[str, State] = {"left": "ACT_LEFT", "right": "ACT_RIGHT"}  # any other sign: ACT_STOP


@dataclass(frozen=True)
class FsmConfig:
    """Controller constants (source C's structure; values tuned for the burger in `maze_arena`)."""

    tick_hz: float = 50.0  # [Hz] control rate
    perception_hz: float = 10.0  # [Hz] detector rate
    publish_hz: float = 5.0  # [Hz] state-JSON rate in APPROACH (at most one request in flight)
    d_goal: float = 0.45  # [m] distance to a sign at which the FSM acts on it
    k_v: float = 0.3  # [1/s] linear gain
    v_min: float = 0.0  # [m/s] lower edge of the admissible box (the robot never reverses)
    v_max: float = 0.06  # [m/s] the source's top setpoint
    v_approach_min: float = 0.02  # [m/s] APPROACH floor: k_v (d - d_goal) alone fades to 0 before d_goal
    k_w: float = 1.5  # [1/s] angular gain on the bearing error
    w_max: float = 0.8  # [rad/s]
    accel_max: float = 0.1  # [m/s^2] first-order rate limit on v
    ang_accel_max: float = 2.0  # [rad/s^2] rate limit on w
    search_w: float = 0.4  # [rad/s] rotation while searching for a sign
    turn_w: float = 0.6  # [rad/s] rotation while acting on a left/right sign
    turn_angle: float = math.pi / 2  # [rad]
    lost_after_s: float = 1.0  # [s] sign unseen this long in APPROACH -> SEARCH
    search_timeout_s: float = 30.0  # [s] SEARCH without any sign -> failure
    pose_sample_s: float = 0.25  # [s] trajectory sampling
    cmd_sample_s: float = 0.1  # [s] command-profile sampling for the log and the PNG


@dataclass(frozen=True)
class Fusion:
    """How the model's suggestion or the smoothing enters the command (the episode's `--assist` options)."""

    assist: Assist = "none"
    alpha: float = 0.5  # weight of the model's suggestion in APPROACH
    beta: float = 0.5  # `ema`: weight of the new baseline


class ControlState(NamedTuple):
    """Everything the controller carries from one tick to the next (a tuple: cheap to make every tick)."""

    state: State = "SEARCH"
    consumed: frozenset[str] = frozenset()  # signs already acted on
    target_id: str | None = None
    last_seen: float = 0.0  # [s] sim time the target was last detected
    state_since: float = 0.0  # [s] sim time of the last state change
    turn_start_yaw: float = 0.0  # [rad] odometry yaw at the last turn sample
    turned: float = 0.0  # [rad] rotation accumulated in ACT_LEFT / ACT_RIGHT
    base_v: float = 0.0  # [m/s] baseline command after the rate limits
    base_w: float = 0.0  # [rad/s]
    out_v: float = 0.0  # [m/s] the command published last
    out_w: float = 0.0  # [rad/s]


class Inputs(NamedTuple):
    """What one tick reads: the sim time, the latest detections of signs, odometry and the model's word."""

    now: float  # [s] sim time
    detections: tuple[Detection, ...]  # the detector's latest sign detections
    yaw: float  # [rad] odometry yaw
    suggestion: tuple[float, float] | None  # (v [m/s], w [rad/s]) accepted and in force, else None


class Step(NamedTuple):
    """What one tick decided."""

    control: ControlState
    v: float  # [m/s] the command to publish
    w: float  # [rad/s]
    raw: tuple[float, float] | None  # the model's suggestion fused into it, if any
    transitions: tuple[tuple[State, State], ...]  # state changes, in order, for the log
    drop_suggestion: bool  # the FSM left APPROACH: a held suggestion no longer applies
    target: Detection | None  # the target as seen this tick (unconsumed), for the state message
    lost: bool = False  # SEARCH timed out without a sign: the episode fails, nothing is published


def saturate(value: float, low: float, high: float) -> float:
    """Clip to [low, high]."""
    return min(max(value, low), high)


def rate_limit(target: float, previous: float, max_rate: float, dt: float) -> float:
    """First-order rate limit: move from `previous` toward `target` by at most max_rate * dt."""
    step = max_rate * dt
    return previous + saturate(target - previous, -step, step)


def tick(cfg: FsmConfig, fusion: Fusion, s: ControlState, inputs: Inputs) -> Step:
    """One control step: state machine, baseline command, fusion. Pure: no clock, no log, no simulator."""
    now = inputs.now
    state, target_id, consumed = s.state, s.target_id, s.consumed
    last_seen, state_since, turn_start_yaw, turned = s.last_seen, s.state_since, s.turn_start_yaw, s.turned
    seen = _unconsumed(inputs.detections, consumed, target_id)
    transitions: tuple[tuple[State, State], ...] = ()  # rare: no list made on an ordinary tick
    drop = False

    # --- state machine ---------------------------------------------------------------------------
    previous = state
    if state == "SEARCH":
        nearest = _nearest_unconsumed(inputs.detections, consumed)
        if nearest is not None:
            target_id, seen = nearest.object_id, nearest
            state, last_seen = "APPROACH", now
        elif now - state_since > cfg.search_timeout_s:
            return Step(s, s.out_v, s.out_w, None, (), False, None, lost=True)
    if state == "APPROACH":
        if seen is not None:
            last_seen = now
            if seen.distance_m <= cfg.d_goal:
                state = _ACT_ON_SIGN.get(seen.sign or "", "ACT_STOP")
        elif now - last_seen > cfg.lost_after_s:
            state = "SEARCH"
    if state != previous:
        state_since = now
        turn_start_yaw, turned = inputs.yaw, 0.0
        if previous == "APPROACH" and state != "SEARCH":
            consumed = consumed | {target_id or ""}
        drop = state != "APPROACH"
        transitions = ((previous, state),)

    # --- baseline command ------------------------------------------------------------------------
    target_v = target_w = 0.0
    if state == "SEARCH":
        target_w = cfg.search_w
    elif state == "APPROACH" and seen is not None:
        target_v = saturate(cfg.k_v * (seen.distance_m - cfg.d_goal), cfg.v_approach_min, cfg.v_max)
        target_w = saturate(cfg.k_w * math.radians(seen.bearing_deg), -cfg.w_max, cfg.w_max)
    elif state in ("ACT_LEFT", "ACT_RIGHT"):
        turned += abs(math.remainder(inputs.yaw - turn_start_yaw, math.tau))
        turn_start_yaw = inputs.yaw
        if turned >= cfg.turn_angle:
            transitions = (*transitions, (state, "SEARCH"))
            state, state_since = "SEARCH", now
        else:
            target_w = cfg.turn_w if state == "ACT_LEFT" else -cfg.turn_w
    dt = 1.0 / cfg.tick_hz
    base_v = rate_limit(target_v, s.base_v, cfg.accel_max, dt)
    base_w = rate_limit(target_w, s.base_w, cfg.ang_accel_max, dt)

    # --- fusion / smoothing ----------------------------------------------------------------------
    raw = None
    if state == "ACT_STOP":
        cmd_v = cmd_w = 0.0
    elif fusion.assist == "ema":
        cmd_v = (1 - fusion.beta) * s.out_v + fusion.beta * base_v
        cmd_w = (1 - fusion.beta) * s.out_w + fusion.beta * base_w
    elif inputs.suggestion is not None and state == "APPROACH":
        raw = inputs.suggestion
        cmd_v = (1 - fusion.alpha) * base_v + fusion.alpha * raw[0]
        cmd_w = (1 - fusion.alpha) * base_w + fusion.alpha * raw[1]
    else:
        cmd_v, cmd_w = base_v, base_w
    control = ControlState(
        state, consumed, target_id, last_seen, state_since, turn_start_yaw, turned, base_v, base_w, cmd_v, cmd_w
    )
    target = seen if state == "APPROACH" else None
    return Step(control, cmd_v, cmd_w, raw, transitions, drop, target)


def _unconsumed(detections: tuple[Detection, ...], consumed: frozenset[str], object_id: str | None) -> Detection | None:
    """The detection of `object_id`, unless that sign was already acted on."""
    if object_id is None or object_id in consumed:
        return None
    for detection in detections:
        if detection.object_id == object_id:
            return detection
    return None


def _nearest_unconsumed(detections: tuple[Detection, ...], consumed: frozenset[str]) -> Detection | None:
    """The nearest detected sign not yet acted on (the first of equals)."""
    nearest = None
    for detection in detections:
        if detection.object_id not in consumed and (nearest is None or detection.distance_m < nearest.distance_m):
            nearest = detection
    return nearest
