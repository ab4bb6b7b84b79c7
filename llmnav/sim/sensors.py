"""The robot's sensors: a 2D LiDAR, an RGB camera and a detector reading the segmentation mask.

The detector decides what is seen from the true scene (mask, range, line of sight) and reports it with
the seeded errors of `DetectorConfig`: range-dependent distance noise and bias, bearing noise, dropout
(docs/sensing.md). Planners only ever get these measured values.

The LiDAR is one batched ray cast, the camera PyBullet's TinyRenderer. TinyRenderer's cost is per
covered pixel (a wall filling the upper half of a 640x480 view costs ~28 ms; bodies out of view or
small ones, cylinders included, cost ~nothing), so fewer or coarser shapes do not help. The EGL plugin
(Mesa llvmpipe) was measured and not adopted: 640x480 in 35 ms CPU against 46 ms, but only by using a
second core (35 -> 45 ms with one llvmpipe thread, no gain for parallel workers), +245 MB and 0.3 s per
process, C-level prints on stdout, and differently lit images (specular highlights, another background).

pybullet and cv2 are imported only where used, so modules that merely need `LidarScan` (the guard's
veto) stay light. Conventions: angles relative to the heading, counter-clockwise positive; bearings
positive to the left; image offsets negative to the left.
"""

from __future__ import annotations

import base64
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from llmnav.core.chat import Image
from llmnav.world.scenario import CameraConfig, DetectorConfig, LidarConfig

if TYPE_CHECKING:
    from llmnav.sim.robot import Robot
    from llmnav.world.scenario import LabelledObject

LIDAR_CLEARANCE = 0.01  # [m] rays start this far outside the robot's body so they never hit it
CAMERA_NEAR = 0.05  # [m] near clipping plane
CAMERA_AHEAD = 0.02  # [m] the camera sits this far in front of the body's edge
DETECTOR_SIZE = (160, 120)  # [px] the detector's own low-resolution segmentation capture
FLOOR_SHADE = 238.0  # TinyRenderer's brightness of a lit upward face, per unit of colour
BACKGROUND_DEPTH = 0.99999  # depth-buffer value from which a pixel counts as empty background


@dataclass
class LidarScan:
    """One planar scan."""

    angles: np.ndarray  # [rad] relative to heading, CCW positive, ascending
    ranges: np.ndarray  # [m] from the robot centre; np.inf where nothing lies within range
    range_max: float = 10.0  # [m] LidarConfig's default
    range_min: float = 0.05  # [m] LidarConfig's default

    def min_in(self, lo_rad: float, hi_rad: float) -> float:
        """Smallest range [m] among rays with lo <= angle <= hi (np.inf if none or all clear)."""
        mask = (self.angles >= lo_rad) & (self.angles <= hi_rad)
        return float(self.ranges[mask].min()) if mask.any() else math.inf


class Lidar:
    """A planar LiDAR at the robot's centre, cast with one `rayTestBatch` per scan."""

    def __init__(
        self, p: Any, client: int, robot: Robot, config: LidarConfig, *, mount_height_m: float | None = None
    ) -> None:
        self._p = p
        self._client = client
        self._robot = robot
        self.config = config
        self.mount_height_m = mount_height_m if mount_height_m is not None else config.mount_height_m  # [m]
        fov = math.radians(config.fov_deg)
        full_circle = config.fov_deg >= 360.0
        self.angles = np.linspace(-fov / 2.0, fov / 2.0, config.rays, endpoint=not full_circle)  # [rad]
        self._cos, self._sin = np.cos(self.angles), np.sin(self.angles)
        # [m] ray origins' distance from the centre: just outside the body, along each ray (a box base's
        # edge is nearer than its corners, and what stands between them must still be seen).
        box = robot.spec.box_m
        if box is None:
            self._start: float | np.ndarray = robot.spec.radius_m + LIDAR_CLEARANCE
        else:
            with np.errstate(divide="ignore"):
                edge = np.minimum(box[0] / 2.0 / np.abs(self._cos), box[1] / 2.0 / np.abs(self._sin))
            self._start = edge + LIDAR_CLEARANCE
        self._z = np.full(config.rays, self.mount_height_m)
        self._rng = np.random.default_rng(0)

    def reseed(self, seed: int) -> None:
        """Restart the noise stream."""
        self._rng = np.random.default_rng(seed)

    def scan(
        self,
        *,
        half_angle: float | None = None,
        max_range: float | None = None,
        rng: np.random.Generator | None = None,
    ) -> LidarScan:
        """Cast the rays from the current ground-truth pose.

        `half_angle` [rad] casts only the rays with |angle| <= it, `max_range` [m] shortens them: cheap
        partial scans for stop checks (ray cost grows with count and length). `rng` draws the range noise
        instead of the sensor's own stream (the collision monitor's scans then leave the planners' scans
        exactly as they were).
        """
        cfg = self.config
        range_m = cfg.range_m if max_range is None else min(max_range, cfg.range_m)  # [m]
        angles, cos, sin, z, start = self.angles, self._cos, self._sin, self._z, self._start
        if half_angle is not None:
            keep = np.abs(angles) <= half_angle
            angles, cos, sin, z = angles[keep], cos[keep], sin[keep], z[keep]
            start = start[keep] if isinstance(start, np.ndarray) else start
        pose = self._robot.pose()
        cy, sy = math.cos(pose.yaw), math.sin(pose.yaw)
        # Ray directions in the world frame: the fixed body-frame fan rotated by the heading.
        dx = cos * cy - sin * sy
        dy = sin * cy + cos * sy
        n = len(angles)
        starts = np.column_stack((pose.x + start * dx, pose.y + start * dy, z))
        ends = np.column_stack((pose.x + range_m * dx, pose.y + range_m * dy, z))
        # In the calling thread: Bullet's helper threads run at ordinary priority, so a real-time control
        # loop waited 10-17 ms for them on a loaded machine (a missed 20 ms slot); one thread gives the
        # same hits and was faster here anyway (360 rays: 1.4 ms against 1.7 ms with numThreads=0).
        hits = self._p.rayTestBatch(starts.tolist(), ends.tolist(), numThreads=1, physicsClientId=self._client)
        fractions = np.fromiter((h[2] if h[0] >= 0 else np.inf for h in hits), dtype=float, count=n)
        ranges = start + fractions * (range_m - start)  # inf where nothing was hit
        if cfg.noise_std_m > 0.0:
            ranges = ranges + (rng or self._rng).normal(0.0, cfg.noise_std_m, n)  # inf stays inf
            ranges = np.where(np.isfinite(ranges), np.clip(ranges, cfg.min_range_m, range_m), np.inf)
        return LidarScan(angles=angles.copy(), ranges=ranges, range_max=range_m, range_min=cfg.min_range_m)


@dataclass
class CameraFrame:
    """One camera image, optionally with its segmentation mask."""

    rgb: np.ndarray  # HxWx3 uint8
    segmentation: np.ndarray | None  # HxW int32 body ids (-1 = background), only when asked
    fov_deg: float = 60.0  # [deg] vertical field of view it was taken with
    jpeg_quality: int = 80  # the scenario's JPEG quality, used by `image()`
    _encoded: dict[int, str] = field(default_factory=dict, repr=False, compare=False)

    def copy(self) -> CameraFrame:
        """The same frame in arrays of its own (a caller may draw on it)."""
        return CameraFrame(
            rgb=self.rgb.copy(),
            segmentation=None if self.segmentation is None else self.segmentation.copy(),
            fov_deg=self.fov_deg,
            jpeg_quality=self.jpeg_quality,
        )

    def jpeg_b64(self, quality: int = 80) -> str:
        """The image as base64 JPEG (what multimodal models receive); encoded once per quality."""
        if quality not in self._encoded:
            # deferred: OpenCV (about 0.13 s) loads only when an image is encoded for a model
            import cv2

            bgr = cv2.cvtColor(self.rgb, cv2.COLOR_RGB2BGR)  # contiguous: cheaper than a reversed view
            ok, buf = cv2.imencode(".jpg", bgr, [int(cv2.IMWRITE_JPEG_QUALITY), int(quality)])
            if not ok:  # pragma: no cover - cv2 only fails on invalid input
                raise RuntimeError("JPEG encoding failed")
            self._encoded[quality] = base64.b64encode(buf.tobytes()).decode("ascii")
        return self._encoded[quality]

    def image(self, quality: int | None = None) -> Image:
        """As a backend `Image` (JPEG at `quality`, default the camera's configured quality)."""
        return Image(self.jpeg_b64(quality if quality is not None else self.jpeg_quality))

    @property
    def horizontal_fov_rad(self) -> float:
        """Horizontal field of view [rad] from the vertical one and the aspect ratio."""
        h, w = self.rgb.shape[:2]
        return 2.0 * math.atan(math.tan(math.radians(self.fov_deg) / 2.0) * w / h)


class Camera:
    """A forward-looking RGB camera at the robot's camera height (TinyRenderer, never shadows).

    The floor is not a body: it is painted into the empty background below the horizon, which looks
    the same as a rendered floor and costs nothing (a floor box doubled the render time).
    """

    def __init__(
        self,
        p: Any,
        client: int,
        robot: Robot,
        config: CameraConfig,
        *,
        mount_height_m: float | None = None,
        floor_color: tuple[float, float, float, float] = (0.55, 0.55, 0.5, 1.0),
    ) -> None:
        self._p = p
        self._client = client
        self._robot = robot
        self.config = config
        self.mount_height_m = mount_height_m if mount_height_m is not None else config.mount_height_m  # [m]
        # The floor as TinyRenderer would shade a lit, upward face of this colour.
        self._floor_rgb = np.array([round(FLOOR_SHADE * c) for c in floor_color[:3]], dtype=np.uint8)
        self._floor_images: dict[tuple[int, int], np.ndarray] = {}  # (width, rows) -> solid floor image
        # The last frame of each (width, height, segmentation) and the view it shows (see `capture`).
        self._last: dict[tuple[int, int, bool], tuple[tuple[Any, ...], CameraFrame]] = {}

    @property
    def raycaster(self) -> tuple[Any, int]:
        """The pybullet module and client the camera renders with (for line-of-sight tests)."""
        return self._p, self._client

    def eye(self) -> tuple[float, float, float]:
        """The camera's position [m]: just in front of the body, so the robot never sees itself."""
        pose = self._robot.pose()
        ahead = self._robot.spec.radius_m + CAMERA_AHEAD
        return (pose.x + ahead * math.cos(pose.yaw), pose.y + ahead * math.sin(pose.yaw), self.mount_height_m)

    def _floor_image(self, width: int, rows: int) -> np.ndarray:
        """A rows x width image of floor colour (cached: the camera renders few resolutions)."""
        image = self._floor_images.get((width, rows))
        if image is None:
            image = np.empty((rows, width, 3), dtype=np.uint8)
            image[:] = self._floor_rgb
            self._floor_images[(width, rows)] = image
        return image

    def capture(
        self, *, segmentation: bool = False, width: int | None = None, height: int | None = None
    ) -> CameraFrame:
        """Render the view along the heading; the segmentation mask only when asked (it costs time)."""
        p, cfg = self._p, self.config
        width = width or cfg.width
        height = height or cfg.height
        if not (16 <= width <= 640 and 16 <= height <= 480):
            raise ValueError(f"camera resolution {width}x{height} outside 16x16..640x480")
        pose = self._robot.pose()
        c, s = math.cos(pose.yaw), math.sin(pose.yaw)
        eye = self.eye()
        target = (eye[0] + c, eye[1] + s, eye[2])
        view = p.computeViewMatrix(eye, target, (0.0, 0.0, 1.0), physicsClientId=self._client)
        proj = p.computeProjectionMatrixFOV(
            cfg.fov_deg, width / height, CAMERA_NEAR, cfg.far_m, physicsClientId=self._client
        )
        # Only the robot moves and bodies are only ever added: the same view of the same bodies is the same
        # image. A robot that has not moved since the last frame (the detector looks again after each leg
        # and at the next decision) gets a copy of it instead of a new render.
        view_key = (*view, *proj, p.getNumBodies(physicsClientId=self._client))
        last = self._last.get((width, height, segmentation))
        if last is not None and last[0] == view_key:
            return last[1].copy()
        frame = self._render(width, height, view, proj, segmentation)
        self._last[(width, height, segmentation)] = (view_key, frame)
        return frame.copy()

    def _render(self, width: int, height: int, view: Any, proj: Any, segmentation: bool) -> CameraFrame:
        """One TinyRenderer frame, the floor painted in below the horizon."""
        p, cfg = self._p, self.config
        flags = 0 if segmentation else p.ER_NO_SEGMENTATION_MASK
        _w, _h, rgba, depth, seg = p.getCameraImage(
            width,
            height,
            viewMatrix=view,
            projectionMatrix=proj,
            shadow=0,  # always explicit: one shadowed call would make later calls shadowed too
            renderer=p.ER_TINY_RENDERER,
            flags=flags,
            physicsClientId=self._client,
        )
        # deferred: OpenCV (about 0.13 s) loads only when the camera renders
        import cv2

        # cv2 drops the alpha channel and paints the floor ~50x faster than numpy slicing and masks.
        rgb = cv2.cvtColor(np.asarray(rgba, dtype=np.uint8).reshape(height, width, 4), cv2.COLOR_RGBA2RGB)
        # The camera looks level, so the horizon is the middle row: empty background below it is floor.
        half = height // 2
        below = np.asarray(depth, dtype=np.float32).reshape(height, width)[half:] >= BACKGROUND_DEPTH
        cv2.copyTo(self._floor_image(width, height - half), below.view(np.uint8), rgb[half:])  # in place
        mask = None
        if segmentation:
            raw = np.asarray(seg, dtype=np.int64).reshape(height, width)
            # Values are body + ((link + 1) << 24); our bodies are single links, so keep the low bits.
            mask = np.where(raw >= 0, raw & ((1 << 24) - 1), -1).astype(np.int32)
        return CameraFrame(rgb=rgb, segmentation=mask, fov_deg=cfg.fov_deg, jpeg_quality=cfg.jpeg_quality)


@dataclass
class Detection:
    """One labelled object seen in the image, as the detector reports it (with its errors)."""

    object_id: str
    label: str
    bearing_deg: float  # [deg] positive = left; measured, so it carries the bearing noise
    distance_m: float  # [m] robot centre -> object goal point; measured, so it carries the distance error
    pixel_fraction: float  # share of the image the object covers
    offset: float  # horizontal offset of its pixel centroid in [-1, 1], negative = left (bearing noise too)
    sign: str | None  # traffic-sign class when the object is a sign


class Detector:
    """Detections read off a segmentation mask, with the error model of `DetectorConfig`.

    Which objects are candidates is decided by what the camera really sees (the mask, and a ray to the
    object's centre with `occlusion: center`); what is reported about them carries seeded errors. The
    noise stream restarts with `reseed` (the world does it on every reset), so a seed repeats exactly.
    """

    def __init__(
        self,
        camera: Camera,
        robot: Robot,
        objects: dict[int, LabelledObject],
        config: DetectorConfig,
    ) -> None:
        self._camera = camera
        self._robot = robot
        self._objects = objects  # body id -> labelled object (shared with the world)
        self.config = config
        self._rng = np.random.default_rng(0)

    def reseed(self, seed: int) -> None:
        """Restart the noise/dropout stream."""
        self._rng = np.random.default_rng(seed)

    def detect(self, frame: CameraFrame | None = None) -> list[Detection]:
        """Detections in `frame` (captures its own 160x120 segmentation frame if none or no mask given).

        `min_pixels` is meant at 160x120 and scaled to the frame's resolution.
        """
        if frame is None or frame.segmentation is None:
            frame = self._camera.capture(segmentation=True, width=DETECTOR_SIZE[0], height=DETECTOR_SIZE[1])
        seg = frame.segmentation
        assert seg is not None
        cfg = self.config
        height, width = seg.shape
        total = width * height
        min_pixels = max(1, round(cfg.min_pixels * total / (DETECTOR_SIZE[0] * DETECTOR_SIZE[1])))
        flat = seg.ravel()
        valid = flat >= 0
        counts = np.bincount(flat[valid], minlength=1)
        cols = np.tile(np.arange(width), height)[valid]
        col_sums = np.bincount(flat[valid], weights=cols, minlength=1)
        pose = self._robot.pose()
        candidates = [
            body
            for body in sorted(self._objects)
            if body < len(counts)
            and counts[body] >= min_pixels
            and pose.distance_to(*self._objects[body].goal_point) <= cfg.max_distance_m
        ]
        if cfg.occlusion == "center" and candidates:
            candidates = self._centre_visible(candidates)
        tan_half = math.tan(frame.horizontal_fov_rad / 2.0)
        out: list[Detection] = []
        for body in candidates:
            obj = self._objects[body]
            # Three draws per candidate, in body order, whatever the configuration: a seed repeats exactly.
            missed, distance_noise, bearing_noise = self._rng.random(), *self._rng.standard_normal(2)
            if missed < cfg.dropout:
                continue
            gx, gy = obj.goal_point
            true_distance = pose.distance_to(gx, gy)
            distance = true_distance * (1.0 + cfg.distance_bias) + cfg.distance_sigma(true_distance) * distance_noise
            bearing_error = math.radians(cfg.bearing_noise_std_deg) * float(bearing_noise)  # [rad] + = left
            # Bearing from the robot centre (like distance_m), not from the camera a little ahead of it.
            bearing = math.degrees(pose.bearing_to(gx, gy) + bearing_error)
            centroid = col_sums[body] / counts[body] + 0.5  # [px] pixel centres
            offset = (centroid - width / 2.0) / (width / 2.0)  # image x over the half width, + = right
            if bearing_error:  # the same angular error moves the centroid (pinhole: x = tan(angle))
                offset = math.tan(math.atan(offset * tan_half) - bearing_error) / tan_half
            out.append(
                Detection(
                    object_id=obj.id,
                    label=obj.label,
                    bearing_deg=bearing,
                    distance_m=max(0.0, float(distance)),
                    pixel_fraction=float(counts[body]) / total,
                    offset=float(min(1.0, max(-1.0, offset))),
                    sign=obj.sign,
                )
            )
        return out

    def _centre_visible(self, bodies: list[int]) -> list[int]:
        """The bodies whose centre the camera sees: one ray each, from the eye to the centre.

        A ray that hits nothing, or hits the object itself, sees it; non-solid objects have no collision
        shape, so only solid scenery can hide a centre. The ray stops 1 cm short so a sign hanging just in
        front of a wall is not hidden by that wall.
        """
        p, client = self._camera.raycaster
        eye = self._camera.eye()
        starts, ends = [], []
        for body in bodies:
            obj = self._objects[body]
            centre = (obj.center[0], obj.center[1], obj.z + obj.height / 2.0)
            span = math.dist(eye, centre)
            stop = max(0.0, span - 0.01) / span if span > 0 else 0.0
            starts.append(eye)
            ends.append(tuple(e + stop * (c - e) for e, c in zip(eye, centre, strict=True)))
        hits = p.rayTestBatch(starts, ends, numThreads=1, physicsClientId=client)
        return [body for body, hit in zip(bodies, hits, strict=True) if hit[0] < 0 or hit[0] == body]
