"""Geometry for the page's SVG figures: paths, poses and LiDAR wedges as numbers.

The templates turn these plain records into SVG elements (through Jinja's escaping `xmlattr`), so no
markup is assembled here. Map layers are in world metres: the template's transform (from
`llmnav.view.basemap`) puts them onto the drawn top view.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from llmnav.view.model import LidarView

POLAR_RADIUS_PX = 150  # [px] radius of the LiDAR plot
POLAR_HEADROOM = 1.25  # the plot reaches this much beyond the farthest finite reading
ARC_POINTS = 10  # segments per sector arc


def svg_point(x: float, y: float) -> tuple[float, float]:
    """A world point [m] for the map's layers, rounded to millimetres (the layer's transform maps it)."""
    return (round(x, 3), round(y, 3))


def points_attr(points: Sequence[Sequence[float]]) -> str:
    """The `points` attribute of a polyline through world points."""
    return " ".join("{:g},{:g}".format(*svg_point(p[0], p[1])) for p in points)


def arrow(pose: Sequence[float], length_m: float) -> dict[str, float]:
    """A heading arrow from a pose: start and tip in SVG units."""
    x, y, yaw = float(pose[0]), float(pose[1]), float(pose[2]) if len(pose) > 2 else 0.0
    x1, y1 = svg_point(x, y)
    x2, y2 = svg_point(x + length_m * math.cos(yaw), y + length_m * math.sin(yaw))
    return {"x1": x1, "y1": y1, "x2": x2, "y2": y2}


# --- LiDAR polar plot ----------------------------------------------------------------------------


def _polar(angle_deg: float, r_px: float) -> tuple[float, float]:
    """Robot frame, forward up, positive angles to the left."""
    a = math.radians(angle_deg)
    return (round(-r_px * math.sin(a), 2), round(-r_px * math.cos(a), 2))


def lidar_wedges(lidar: LidarView, radius_px: float = POLAR_RADIUS_PX) -> dict[str, Any]:
    """Each sector as a wedge out to its closest reading (full radius, dashed, for inf or no data).

    The plot reaches a little beyond the farthest finite reading (at most the sensor's range), so
    near obstacles do not shrink to a few pixels when the range is long.
    """
    finite = [s.min_m for s in lidar.sectors if s.min_m is not None and math.isfinite(s.min_m)]
    reach = min(lidar.range_max_m, max(finite) * POLAR_HEADROOM) if finite else lidar.range_max_m
    reach = max(reach, 0.5)
    scale = radius_px / reach
    wedges = []
    for number, sector in enumerate(lidar.sectors, start=1):
        if sector.min_m is None:
            r, kind, text = radius_px, "nodata", "no data"
        elif math.isinf(sector.min_m):
            r, kind, text = radius_px, "open", "inf"
        else:
            r = min(radius_px, sector.min_m * scale)
            kind, text = ("near" if sector.min_m < 1.0 else "seen"), f"{sector.min_m:.2f}"
        arc = [
            _polar(sector.start_deg + (sector.end_deg - sector.start_deg) * k / ARC_POINTS, r)
            for k in range(ARC_POINTS + 1)
        ]
        points = " ".join(f"{x:g},{y:g}" for x, y in [(0.0, 0.0), *arc])
        mid = (sector.start_deg + sector.end_deg) / 2
        lx, ly = _polar(mid, radius_px + 14)
        dot = None
        if sector.angle_deg is not None and sector.min_m is not None and math.isfinite(sector.min_m):
            dot = _polar(sector.angle_deg, r)
        wedges.append(
            {
                "number": number,
                "points": points,
                "kind": kind,
                "text": text,
                "label_x": lx,
                "label_y": ly,
                "dot": dot,
                "title": f"sector {number}: {sector.start_deg:+.1f}° to {sector.end_deg:+.1f}°, closest {text}"
                + (" m" if kind in ("near", "seen") else ""),
            }
        )
    rings = []
    for metres in (0.5, 1, 2, 5, 10, 20):
        if metres < reach and (metres >= reach / 8):
            rings.append({"r": round(metres * scale, 2), "label": f"{metres:g} m"})
    return {"wedges": wedges, "rings": rings, "radius": radius_px, "range_max": lidar.range_max_m, "reach": reach}
