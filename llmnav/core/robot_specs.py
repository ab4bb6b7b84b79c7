"""Robot models: the physical numbers of the two differential-drive bases (no pybullet import)."""

from __future__ import annotations

from dataclasses import dataclass, replace


@dataclass(frozen=True)
class RobotSpec:
    """A round differential-drive base; every number carries its unit."""

    name: str
    radius_m: float  # [m] footprint radius: the collision cylinder's, or the circumradius of a box base
    height_m: float  # [m] body height
    mass_kg: float  # [kg]
    wheel_radius_m: float  # [m]
    half_track_m: float  # [m] half the distance between the wheels
    max_wheel_speed: float  # [rad/s]
    max_linear: float  # [m/s] speed limit for discrete moves
    max_angular: float  # [rad/s] speed limit for discrete turns
    lidar_height_m: float  # [m]
    camera_height_m: float  # [m]
    color: tuple[float, float, float, float]
    # [m] (length along the heading, width) of a rectangular base; None: the base is the disc of `radius_m`
    box_m: tuple[float, float] | None = None

    @property
    def width_m(self) -> float:
        """Footprint width [m] (what the safety veto sweeps)."""
        return self.box_m[1] if self.box_m is not None else 2.0 * self.radius_m


# PR2-like base for the factory: wheel 0.08 m, 6 rad/s max wheel speed (~0.48 m/s), half track 0.318 m
# (numbers of the stepwise source's robot); footprint 0.67 m square approximated by its inscribed circle
# plus a little.
PR2 = RobotSpec(
    name="pr2",
    radius_m=0.36,
    height_m=1.2,
    mass_kg=80.0,
    wheel_radius_m=0.08,
    half_track_m=0.318,
    max_wheel_speed=6.0,
    max_linear=0.08 * 6.0,
    max_angular=0.08 * 6.0 / 0.318,
    lidar_height_m=0.28,
    camera_height_m=1.2,
    color=(0.85, 0.85, 0.9, 1.0),
)

# TurtleBot3-Burger-like base; the waypoint source drives it at 0.4 m/s and 2.0 rad/s.
BURGER = RobotSpec(
    name="burger",
    radius_m=0.105,
    height_m=0.19,
    mass_kg=1.0,
    wheel_radius_m=0.033,
    half_track_m=0.08,
    max_wheel_speed=0.4 / 0.033,
    max_linear=0.4,
    max_angular=2.0,
    lidar_height_m=0.17,
    camera_height_m=0.19,
    color=(0.2, 0.2, 0.25, 1.0),
)

# The PR2's real base: a 0.668 m square. Turning in place sweeps its circumcircle (radius 0.47 m), so a
# turn beside a wall end can touch it, which the round `pr2` never does; maps inflate by that radius.
PR2_SQUARE = replace(PR2, name="pr2-square", radius_m=0.4724, box_m=(0.668, 0.668))

ROBOT_SPECS: dict[str, RobotSpec] = {"pr2": PR2, "burger": BURGER, "pr2-square": PR2_SQUARE}
