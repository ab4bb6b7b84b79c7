"""Safety veto: whether a straight move (FRONT or BACK) may go ahead, judged only from the LiDAR scan.

The check sweeps the robot's footprint along the move: a rectangle in the robot frame starting at the
robot's centre, pointing in the direction of motion (+x for FRONT, -x for BACK), of half-width
`robot_width/2 + margin` and length `|distance| + stop_margin + robot_radius` (the robot's leading edge
travels `|distance|` and must still stop `stop_margin` short of anything). Any finite LiDAR return inside
that rectangle blocks the move. The source system only compared the minimum range in a 30° frontal window
with the requested distance and never checked BACK; this is stricter on both counts.

With `footprint="disc"` the swept area is the round base's own: every point within `robot_radius + margin`
of the centre's straight path, with the stop margin kept along it (what a go_to leg of a round robot
really covers; the box's front corners overreach it, which matters on legs planned close to a wall).
`direction_rad` turns the check toward a leg that does not start straight ahead (go_to turns in place
first; a round base sweeps nothing new while turning).

Unknown is unsafe: if the scan has no rays covering the direction of motion (a forward-only LiDAR asked
about BACK, a malformed or empty scan, NaN readings), the move is blocked.

Nothing here reads model text: the inputs are a number and a sensor scan, so no wording in an answer can
loosen the check. Rotations in place are not checked (a round base sweeps no new area when turning).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

if TYPE_CHECKING:
    from llmnav.sim.sensors import LidarScan  # noqa: F401 - documentation of the duck type

MAX_COVERAGE_GAP_DEG = 10.0  # [deg] largest angular gap between rays tolerated over the path's cone


@dataclass(frozen=True)
class VetoResult:
    """The veto's verdict on one move."""

    allowed: bool
    # [m] free distance from the robot's leading edge to the first LiDAR return inside the swept corridor
    # (along the direction of motion); inf when the corridor is empty as far as the scan sees, 0 when
    # something is already inside the footprint. The largest safe move is `clearance_m - stop_margin`.
    clearance_m: float
    reason: str | None  # one sentence for the model and the log when blocked
    # [m] robot-frame (x ahead, y left) position of the return that blocked the move, when one did
    hit: tuple[float, float] | None = None


def _blocked(reason: str, clearance_m: float = 0.0, hit: tuple[float, float] | None = None) -> VetoResult:
    return VetoResult(False, clearance_m, reason, hit)


def _covered(offsets: np.ndarray, half_cone: float) -> bool:
    """Whether ray offsets [rad] from the motion direction cover [-half_cone, half_cone] without big gaps."""
    gap = math.radians(MAX_COVERAGE_GAP_DEG)
    near = np.sort(offsets[np.abs(offsets) <= half_cone + gap])
    if near.size == 0:
        return False
    if near[0] > -half_cone + gap / 2 or near[-1] < half_cone - gap / 2:
        return False
    return bool(near.size == 1 or np.max(np.diff(near)) <= gap)


def check_motion(
    distance_m: float,
    scan: Any,
    *,
    robot_width_m: float,
    margin_m: float = 0.15,
    stop_margin_m: float = 0.2,
    robot_radius_m: float | None = None,
    direction_rad: float = 0.0,
    footprint: Literal["box", "disc"] = "box",
) -> VetoResult:
    """Check a straight move of `distance_m` [m] (+ forward, - backward) against a LiDAR scan.

    `scan` is a `llmnav.sim.sensors.LidarScan` or anything with `.angles` [rad, CCW+, relative to the
    heading] and `.ranges` [m, inf beyond range]. `robot_radius_m` defaults to half the width (round base).
    `direction_rad` [rad, CCW+] is the direction of travel relative to the heading (0: straight ahead).
    `footprint` picks the swept shape (see the module docstring). Never raises on a bad scan: it blocks.
    """
    radius = robot_width_m / 2.0 if robot_radius_m is None else robot_radius_m
    if not all(math.isfinite(v) and v >= 0 for v in (robot_width_m, margin_m, stop_margin_m, radius)):
        raise ValueError("robot_width_m, margin_m, stop_margin_m and robot_radius_m must be finite and >= 0")
    if not isinstance(distance_m, int | float) or not math.isfinite(distance_m) or not math.isfinite(direction_rad):
        return _blocked(f"the move distance {distance_m!r} is not a finite number")
    direction = "ahead" if distance_m >= 0 else "behind"
    try:
        angles = np.asarray(scan.angles, dtype=float).ravel()
        ranges = np.asarray(scan.ranges, dtype=float).ravel()
    except (AttributeError, TypeError, ValueError):
        return _blocked("the LiDAR scan is unreadable, so the move cannot be checked; choose another action")
    if angles.size == 0 or angles.shape != ranges.shape:
        return _blocked("the LiDAR scan is empty or malformed, so the move cannot be checked")

    half_width = robot_width_m / 2.0 + margin_m  # [m]
    length = abs(distance_m) + stop_margin_m + radius  # [m] from the centre to the end of the swept area
    heading = direction_rad + (0.0 if distance_m >= 0 else math.pi)
    valid = np.isfinite(angles) & ~np.isnan(ranges)
    offsets = (angles[valid] - heading + math.pi) % (2.0 * math.pi) - math.pi
    # The cone in which the far end of the corridor is seen must be covered by rays.
    if not _covered(offsets, math.atan2(half_width, length)):
        return _blocked(
            f"the LiDAR does not see the path {direction}, so the move cannot be checked; choose another action"
        )

    # Finite returns in the motion frame (`along` the direction of motion, `lateral` across it). A reading
    # below range_min is kept: "too close to measure" is the most dangerous case, not a free path.
    hit = np.isfinite(ranges) & np.isfinite(angles)
    r, a = ranges[hit], angles[hit]
    along = r * np.cos(a - heading)
    lateral = np.abs(r * np.sin(a - heading))
    verb = "FRONT" if distance_m >= 0 else "BACK"
    if footprint == "disc":
        # How far the centre may travel before the disc of radius `half_width` touches each return.
        reach = half_width
        near = (lateral <= reach) & (along >= 0.0)
        travel = along[near] - np.sqrt(np.maximum(reach**2 - lateral[near] ** 2, 0.0))
        index = int(np.argmin(travel)) if travel.size else -1
        clearance = max(0.0, float(travel[index])) if travel.size else math.inf
        limit = abs(distance_m) + stop_margin_m
    else:
        in_strip = (lateral <= half_width) & (along >= 0.0)
        near = in_strip
        travel = along[in_strip]
        index = int(np.argmin(travel)) if travel.size else -1
        first = float(travel[index]) if travel.size else math.inf  # [m] from the centre
        clearance = max(0.0, first - radius)
        limit = length - radius
    if travel.size and float(travel[index]) + (0.0 if footprint == "disc" else -radius) <= limit:
        which = np.flatnonzero(near)[index]
        point = (float(r[which] * math.cos(a[which])), float(r[which] * math.sin(a[which])))
        safe = max(0.0, clearance - stop_margin_m)
        return _blocked(
            f"{verb} {abs(distance_m):.2f} m would collide with an obstacle {clearance:.2f} m {direction} "
            f"(at most {safe:.2f} m is safe); choose another action",
            clearance,
            point,
        )
    return VetoResult(True, clearance, None)


VETO_PREFIX = "Safety check: your action was NOT executed"  # how every veto follow-up begins


def veto_message(result: VetoResult) -> str:
    """The follow-up telling the model its action was refused and why."""
    if result.allowed:
        raise ValueError("veto_message needs a blocked result")
    return (
        f"{VETO_PREFIX}, it is dangerous: {result.reason}. "
        "Answer again in the same JSON format with a different action (for example a turn or a shorter move)."
    )
