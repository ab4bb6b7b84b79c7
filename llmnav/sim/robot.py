"""A physics-stepped differential-drive base: one cylinder body driven by its base velocity.

Design: the base is a single cylinder (a box for a rectangular `RobotSpec.box_m`) with mass, floating a
millimetre above the floor plane in a gravity-free world (there is no floor body, so no floor contacts
accumulate). Before every physics step its velocity is set from the commanded (v, w), limited by the
wheel-speed and acceleration limits; walls and obstacles are static bodies, so the solver stops it at
them and nothing passes through.
Roll, pitch and height are pinned back whenever a contact disturbs them.

The body's inertial frame is its link frame, so `getBasePositionAndOrientation` (which reports the
centre of mass) is also the link pose; `pose()` is exact ground truth, the only pose scoring uses.

`odom()` is what wheel encoders give: the body's motion along its heading (sideways slip is invisible to
them) split into the travel of the two wheels, each read with the errors of `OdometryConfig` - a
per-episode radius error per wheel and track-width error (systematic: UMBmark's E_d and E_b), and a
random walk per wheel whose variance grows with the distance it rolled - then integrated back into a
pose. The errors are drawn from the episode seed, so a run repeats exactly.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from llmnav.core.geometry import Pose2D, wrap_angle
from llmnav.core.robot_specs import RobotSpec
from llmnav.sim.bodies import ROBOT_GROUP, SCENERY_GROUP
from llmnav.world.scenario import OdometryConfig

CONTACT_DISTANCE = 0.002  # [m] a contact point closer than this counts as touching
NOISE_BLOCK = 4096  # wheel-noise draws fetched from the generator at a time (one per wheel per step)


def _yaw_of(q: tuple[float, float, float, float]) -> float:
    x, y, z, w = q
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


class Robot:
    """The simulated base. Its world calls `_before_step`/`_after_step` around each physics step."""

    def __init__(
        self,
        p: Any,
        client: int,
        spec: RobotSpec,
        *,
        dt: float,
        body_names: dict[int, str],
        odometry: OdometryConfig | None = None,
        max_linear_acc: float | None = None,
        max_angular_acc: float | None = None,
    ) -> None:
        self._p = p
        self._client = client
        self.spec = spec
        self._dt = dt  # [s] physics step
        self._body_names = body_names  # shared with the world: body id -> name
        self.odometry = odometry if odometry is not None else OdometryConfig()
        self._odometry_exact = self.odometry.is_exact  # checked every physics step
        self.max_linear_acc = (
            max_linear_acc if max_linear_acc is not None else max(1.0, 2.0 * spec.max_linear)
        )  # [m/s^2]
        self.max_angular_acc = max_angular_acc if max_angular_acc is not None else 2.0 * spec.max_angular  # [rad/s^2]
        self._z = spec.height_m / 2.0 + 0.001  # [m] base centre height (a hair above the floor)
        if spec.box_m is not None:  # a rectangular base: its true shape, not its circumcircle
            half = (spec.box_m[0] / 2.0, spec.box_m[1] / 2.0, spec.height_m / 2.0)
            col = p.createCollisionShape(p.GEOM_BOX, halfExtents=half, physicsClientId=client)
            vis = p.createVisualShape(p.GEOM_BOX, halfExtents=half, rgbaColor=spec.color, physicsClientId=client)
        else:
            col = p.createCollisionShape(
                p.GEOM_CYLINDER, radius=spec.radius_m, height=spec.height_m, physicsClientId=client
            )
            vis = p.createVisualShape(
                p.GEOM_CYLINDER,
                radius=spec.radius_m,
                length=spec.height_m,
                rgbaColor=spec.color,
                physicsClientId=client,
            )
        self.body = int(
            p.createMultiBody(
                baseMass=spec.mass_kg,
                baseCollisionShapeIndex=col,
                baseVisualShapeIndex=vis,
                basePosition=(0.0, 0.0, self._z),
                physicsClientId=client,
            )
        )
        p.setCollisionFilterGroupMask(self.body, -1, ROBOT_GROUP, SCENERY_GROUP, physicsClientId=client)
        p.changeDynamics(
            self.body,
            -1,
            lateralFriction=0.0,
            spinningFriction=0.0,
            rollingFriction=0.0,
            restitution=0.0,
            linearDamping=0.0,
            angularDamping=0.0,
            physicsClientId=client,
        )
        self._rng = np.random.default_rng(0)
        self._wheel_scale = (1.0, 1.0)  # this episode's (right, left) travel factors
        self._track_scale = 1.0  # this episode's factor on the track width odometry assumes
        self._noise_scale = self.odometry.wheel_noise_m_per_sqrt_m  # [m/sqrt(m)] random walk of each wheel
        self._noise: list[list[float]] = []  # pre-drawn standard normals, [right, left] per physics step
        self._noise_at = 0
        self._cmd = (0.0, 0.0)  # commanded (v, w), already limited
        self._vel = (0.0, 0.0)  # acceleration-limited (v, w) applied to the body
        self._pose = Pose2D(0.0, 0.0, 0.0)  # ground truth, refreshed after each step (read several times a step)
        self._odom = Pose2D(0.0, 0.0, 0.0)

    # --- public interface ---------------------------------------------------------------------
    def pose(self) -> Pose2D:
        """Ground-truth pose (link frame = centre of mass for this body)."""
        return self._pose

    def engine_pose(self) -> Pose2D:
        """The body's pose as the physics engine holds it now (`pose` is the copy refreshed after each step)."""
        (x, y, _z), q = self._p.getBasePositionAndOrientation(self.body, physicsClientId=self._client)
        return Pose2D(x, y, _yaw_of(q))

    def odom(self) -> Pose2D:
        """Odometry pose: integrated from the measured wheel motion since the last reset."""
        return self._odom

    def set_velocity(self, v: float, w: float) -> None:
        """Command a forward speed [m/s] and turn rate [rad/s]; clipped to the spec and wheel limits."""
        spec = self.spec
        v = min(max(v, -spec.max_linear), spec.max_linear)
        w = min(max(w, -spec.max_angular), spec.max_angular)
        # Wheel speed limit: scale both together so the path's curvature is kept.
        wheel = (abs(v) + abs(w) * spec.half_track_m) / spec.wheel_radius_m  # [rad/s] faster wheel
        if wheel > spec.max_wheel_speed:
            scale = spec.max_wheel_speed / wheel
            v, w = v * scale, w * scale
        self._cmd = (v, w)

    def command(self) -> tuple[float, float]:
        """The current (limited) command (v [m/s], w [rad/s])."""
        return self._cmd

    def velocity(self) -> tuple[float, float]:
        """The acceleration-limited (v [m/s], w [rad/s]) currently applied."""
        return self._vel

    def halt(self) -> None:
        """Stop dead (brakes): command and applied velocity both zero, body velocity cleared."""
        self._cmd = (0.0, 0.0)
        self._vel = (0.0, 0.0)
        self._p.resetBaseVelocity(self.body, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), physicsClientId=self._client)

    def contact_points(self) -> list[tuple[int, float, float, float]]:
        """Touching contacts now: (body id, normal x, normal y, distance [m]); normal points at the robot."""
        out = []
        for c in self._p.getContactPoints(bodyA=self.body, physicsClientId=self._client):
            if c[8] < CONTACT_DISTANCE:
                out.append((int(c[2]), float(c[7][0]), float(c[7][1]), float(c[8])))
        return out

    def contact_points_at(self) -> list[tuple[int, float, float, float, float, float]]:
        """Touching contacts with where they are: (body, normal x, normal y, distance [m], x [m], y [m])."""
        out = []
        for c in self._p.getContactPoints(bodyA=self.body, physicsClientId=self._client):
            if c[8] < CONTACT_DISTANCE:
                out.append((int(c[2]), float(c[7][0]), float(c[7][1]), float(c[8]), float(c[5][0]), float(c[5][1])))
        return out

    def contacts(self) -> list[str]:
        """Names of the bodies touched now (floor never included): object ids, wall/obstacle names."""
        names: list[str] = []
        for body, _nx, _ny, _d in self.contact_points():
            name = self._body_names.get(body, f"body:{body}")
            if name not in names:
                names.append(name)
        return names

    # --- world hooks ----------------------------------------------------------------------------
    def _reset(self, start: Pose2D, seed: int) -> None:
        p, client = self._p, self._client
        p.resetBasePositionAndOrientation(
            self.body,
            (start.x, start.y, self._z),
            (0.0, 0.0, math.sin(start.yaw / 2.0), math.cos(start.yaw / 2.0)),
            physicsClientId=client,
        )
        p.resetBaseVelocity(self.body, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), physicsClientId=client)
        self._rng = np.random.default_rng(seed)
        odo = self.odometry
        right, left, track = self._rng.standard_normal(3)  # the episode's systematic errors
        self._wheel_scale = (1.0 + odo.wheel_scale_std * float(right), 1.0 + odo.wheel_scale_std * float(left))
        self._track_scale = 1.0 + odo.track_scale_std * float(track)
        self._noise_scale = odo.wheel_noise_m_per_sqrt_m  # [m/sqrt(m)]
        self._noise, self._noise_at = [], 0
        self._cmd = (0.0, 0.0)
        self._vel = (0.0, 0.0)
        self._pose = Pose2D(start.x, start.y, wrap_angle(start.yaw))
        self._odom = self._pose

    def _before_step(self) -> None:
        # Move the applied velocity toward the command within the acceleration limits, then set it.
        v, w = self._vel
        cv, cw = self._cmd
        dv = self.max_linear_acc * self._dt
        dw = self.max_angular_acc * self._dt
        v += min(max(cv - v, -dv), dv)
        w += min(max(cw - w, -dw), dw)
        self._vel = (v, w)
        yaw = self._pose.yaw
        c, s = math.cos(yaw), math.sin(yaw)
        self._p.resetBaseVelocity(self.body, (v * c, v * s, 0.0), (0.0, 0.0, w), physicsClientId=self._client)

    def _after_step(self) -> None:
        p, client = self._p, self._client
        (x, y, z), q = p.getBasePositionAndOrientation(self.body, physicsClientId=client)
        yaw = _yaw_of(q)
        if abs(q[0]) + abs(q[1]) > 1e-6 or abs(z - self._z) > 1e-5:
            # A contact tipped or lifted the base: pin it back upright at its height.
            p.resetBasePositionAndOrientation(
                self.body,
                (x, y, self._z),
                (0.0, 0.0, math.sin(yaw / 2.0), math.cos(yaw / 2.0)),
                physicsClientId=client,
            )
        # Odometry: the heading-wise displacement and the yaw change, as wheel encoders would see them.
        last = self._pose
        dyaw = wrap_angle(yaw - last.yaw)
        mid = last.yaw + dyaw / 2.0
        ds = (x - last.x) * math.cos(mid) + (y - last.y) * math.sin(mid)
        if not self._odometry_exact:
            ds, dyaw = self._measured(ds, dyaw)
        o = self._odom
        omid = o.yaw + dyaw / 2.0
        self._odom = Pose2D(o.x + ds * math.cos(omid), o.y + ds * math.sin(omid), wrap_angle(o.yaw + dyaw))
        self._pose = Pose2D(x, y, yaw)

    def _measured(self, ds: float, dyaw: float) -> tuple[float, float]:
        """What the encoders report for a true step of `ds` [m] along the heading and `dyaw` [rad]."""
        if self._noise_at >= len(self._noise):  # plain floats: numpy scalars cost ~10x more per step
            self._noise, self._noise_at = self._rng.standard_normal((NOISE_BLOCK, 2)).tolist(), 0
        normals = self._noise[self._noise_at]
        self._noise_at += 1
        # Positional: this runs every physics step, where keyword passing is a measurable share.
        return wheel_odometry(
            ds, dyaw, self.spec.half_track_m, self._wheel_scale, self._track_scale, self._noise_scale, normals
        )


def wheel_odometry(
    ds: float,
    dyaw: float,
    half_track_m: float,
    wheel_scale: tuple[float, float],
    track_scale: float,
    noise_m_per_sqrt_m: float,
    normals: Sequence[float],
) -> tuple[float, float]:
    """One odometry increment (ds [m], dyaw [rad]) as wheel encoders measure a true (ds, dyaw).

    The true step is split into the travel of the right and left wheel, each scaled by its radius error
    (`wheel_scale`, 1 = exact) and given a random error of std noise * sqrt(|travel|) (`normals` are the
    two standard-normal draws), then recombined with a track width off by `track_scale`.
    """
    right = ds + half_track_m * dyaw  # [m] true travel of each wheel
    left = ds - half_track_m * dyaw
    right = right * wheel_scale[0] + noise_m_per_sqrt_m * math.sqrt(abs(right)) * normals[0]
    left = left * wheel_scale[1] + noise_m_per_sqrt_m * math.sqrt(abs(left)) * normals[1]
    return (right + left) / 2.0, (right - left) / (2.0 * half_track_m * track_scale)
