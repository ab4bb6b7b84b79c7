"""Sensor data as text for language models: LiDAR sectors, front distance, detections, pose.

Pure functions on duck-typed inputs: a scan is anything with `.angles` [rad, CCW positive, relative to
the heading] and `.ranges` [m, inf where nothing is within range] (optionally `.range_max` [m]); a
detection anything with the fields of `llmnav.sim.sensors.Detection`.

The LiDAR summary follows the stepwise source (docs/sources.md, A): the field of view centred on the heading is cut
into N equal sectors, each reported by its closest reading and the angle of that reading, plus a front
distance. Model-facing text uses degrees, positive = to the robot's left, and `inf` for "nothing within
range"; a sector that no ray covers says "no data" (unknown is not the same as open).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from llmnav.core.geometry import Pose2D

FRONT_RAYS = 7  # readings averaged for the front distance (the stepwise source's central 7)
FRONT_WINDOW_DEG = 10.0  # [deg] the central readings must lie within ± this of straight ahead


@dataclass(frozen=True)
class Sector:
    """One angular sector of the scan; angles [deg], positive = left."""

    start_deg: float  # left edge (the larger angle)
    end_deg: float  # right edge
    min_m: float  # [m] closest reading in the sector; inf when every ray sees nothing in range
    min_angle_deg: float | None  # [deg] where the closest reading lies; None when no finite reading
    rays: int  # rays falling in the sector (0 = no data)


def _arrays(scan: Any) -> tuple[np.ndarray, np.ndarray]:
    """Angles wrapped to [-pi, pi) [rad] and ranges [m] of the usable rays (NaNs dropped)."""
    angles = np.asarray(scan.angles, dtype=float).ravel()
    ranges = np.asarray(scan.ranges, dtype=float).ravel()
    if angles.shape != ranges.shape:
        raise ValueError(f"scan has {angles.size} angles but {ranges.size} ranges")
    keep = np.isfinite(angles) & ~np.isnan(ranges)
    wrapped = (angles[keep] + math.pi) % (2.0 * math.pi) - math.pi
    return wrapped, ranges[keep]


def lidar_sectors(scan: Any, n_sectors: int = 8, fov_deg: float = 90.0) -> list[Sector]:
    """`n_sectors` equal sectors over `fov_deg` centred on the heading, ordered left to right.

    Left to right matches how the camera image reads. A ray on the boundary between two sectors belongs
    to the one on its right, except at the right edge of the field, which is inclusive.
    """
    if n_sectors < 1:
        raise ValueError("n_sectors must be at least 1")
    if not 0.0 < fov_deg <= 360.0:
        raise ValueError("fov_deg must be in (0, 360]")
    angles, ranges = _arrays(scan)
    half = math.radians(fov_deg) / 2.0
    width = 2.0 * half / n_sectors
    # Index 0 = leftmost sector. Distance of each ray from the left edge, in sector widths.
    position = (half - angles) / width
    inside = (angles <= half + 1e-9) & (angles >= -half - 1e-9)
    index = np.clip(np.floor(position + 1e-9).astype(int), 0, n_sectors - 1)
    sectors: list[Sector] = []
    for i in range(n_sectors):
        left = math.degrees(half - i * width)
        right = math.degrees(half - (i + 1) * width)
        mask = inside & (index == i)
        r, a = ranges[mask], angles[mask]
        finite = np.isfinite(r)
        if finite.any():
            j = int(np.argmin(np.where(finite, r, np.inf)))
            sectors.append(Sector(left, right, float(r[j]), math.degrees(float(a[j])), int(mask.sum())))
        else:
            sectors.append(Sector(left, right, math.inf, None, int(mask.sum())))
    return sectors


def front_distance(scan: Any, n_rays: int = FRONT_RAYS) -> float | None:
    """Free distance straight ahead [m]: the mean of the `n_rays` readings nearest to 0°.

    Readings of `inf` (nothing in range) are left out of the mean, so one ray hitting a thin pole still
    shows; all `inf` gives inf. None when no ray lies within ±FRONT_WINDOW_DEG of the heading.
    """
    angles, ranges = _arrays(scan)
    near = np.abs(angles) <= math.radians(FRONT_WINDOW_DEG)
    if not near.any():
        return None
    order = np.argsort(np.abs(angles[near]))[:n_rays]
    central = ranges[near][order]
    finite = central[np.isfinite(central)]
    return float(finite.mean()) if finite.size else math.inf


def _metres(value: float | None) -> str:
    if value is None:
        return "no data"
    return "inf" if math.isinf(value) else f"{value:.2f}"


@dataclass(frozen=True)
class LidarSummary:
    """Front distance and sectors of one scan, and how to say them to a model."""

    front_m: float | None  # [m] see `front_distance`
    sectors: list[Sector]
    fov_deg: float  # [deg]
    range_max: float | None  # [m]

    def text(self) -> str:
        """Compact text: one line for the front distance, one per sector (left to right)."""
        beyond = f"inf = nothing within {self.range_max:g} m" if self.range_max else "inf = nothing in range"
        lines = [
            f"Front distance: {_metres(self.front_m)} m",
            f"LiDAR sectors over a {self.fov_deg:g} deg field centred ahead, left to right "
            f"(angles in deg, positive = left; {beyond}):",
        ]
        for number, s in enumerate(self.sectors, start=1):
            span = f"{s.start_deg:+.1f} to {s.end_deg:+.1f} deg"
            if s.rays == 0:
                lines.append(f"{number}. {span}: no data")
            elif s.min_angle_deg is None:
                lines.append(f"{number}. {span}: closest inf")
            else:
                lines.append(f"{number}. {span}: closest {_metres(s.min_m)} m at {s.min_angle_deg:+.1f} deg")
        return "\n".join(lines)


def summarize_scan(scan: Any, sectors: int = 8, fov_deg: float = 90.0) -> LidarSummary:
    """Front distance and `sectors` sectors over `fov_deg` of a scan."""
    range_max = getattr(scan, "range_max", None)
    return LidarSummary(
        front_distance(scan),
        lidar_sectors(scan, sectors, fov_deg),
        fov_deg,
        float(range_max) if range_max is not None and math.isfinite(range_max) else None,
    )


def lidar_text(scan: Any, n_sectors: int = 8, fov_deg: float = 90.0) -> str:
    """The LiDAR summary as model-facing text (see `LidarSummary.text`)."""
    return summarize_scan(scan, n_sectors, fov_deg).text()


def _side(bearing_deg: float) -> str:
    if abs(bearing_deg) < 5.0:
        return "ahead"
    return "left" if bearing_deg > 0 else "right"


def detections_text(detections: Iterable[Any]) -> str:
    """Detected objects, nearest first, one a line (for text-only models)."""
    items = sorted(detections, key=lambda d: d.distance_m)
    if not items:
        return "Detected objects: none in view."
    lines = ["Detected objects (bearing in deg, positive = left):"]
    for d in items:
        sign = f", sign: {d.sign}" if getattr(d, "sign", None) else ""
        lines.append(
            f"- {d.label} [id {d.object_id}]: {d.distance_m:.1f} m, bearing {d.bearing_deg:+.0f} deg "
            f"({_side(d.bearing_deg)}){sign}"
        )
    return "\n".join(lines)


describe_detections = detections_text  # the name llmnav.planners.observe uses


def pose_text(pose: Pose2D) -> str:
    """A pose as text: position [m] and heading [deg], 0 = +x, counter-clockwise positive."""
    heading = math.degrees(pose.yaw)
    return f"x {pose.x:.2f} m, y {pose.y:.2f} m, heading {heading:.0f} deg (0 = +x, CCW positive)"
