"""Geometry for the page's SVG figures: world shapes, poses and LiDAR wedges as numbers.

The templates turn these plain records into SVG elements (through Jinja's escaping `xmlattr`), so no
markup is assembled here. World figures use metres with y flipped (SVG's y grows downwards): a world
point (x, y) is drawn at (x, -y).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from llmnav.scenario import Scenario, Shape
    from llmnav.view.model import LidarView

MAP_MARGIN_M = 0.4  # [m] around the scenario bounds
POLAR_RADIUS_PX = 150  # [px] radius of the LiDAR plot
POLAR_HEADROOM = 1.25  # the plot reaches this much beyond the farthest finite reading
ARC_POINTS = 10  # segments per sector arc


def rgb(color: Sequence[float]) -> str:
    """`rgb(r,g,b)` from a 0–1 RGB(A) tuple."""
    r, g, b = (max(0, min(255, round(255 * float(c)))) for c in color[:3])
    return f"rgb({r},{g},{b})"


def svg_point(x: float, y: float) -> tuple[float, float]:
    """World [m] → SVG user units (y flipped), rounded to millimetres."""
    return (round(x, 3), round(-y, 3))


def points_attr(points: Sequence[Sequence[float]]) -> str:
    """The `points` attribute of a polyline through world points."""
    return " ".join("{:g},{:g}".format(*svg_point(p[0], p[1])) for p in points)


@dataclass
class MapFrame:
    """The world view box and a text size that reads at any map size."""

    x0: float
    y0: float  # SVG top (= -max world y)
    width: float
    height: float

    @property
    def view_box(self) -> str:
        """The `viewBox` attribute."""
        return f"{self.x0:g} {self.y0:g} {self.width:g} {self.height:g}"

    @property
    def font_m(self) -> float:
        """Label font size [m]."""
        return round(max(self.width, self.height) * 0.018, 3)

    @property
    def marker_m(self) -> float:
        """Decision marker radius [m]."""
        return round(max(self.width, self.height) * 0.008, 3)


def map_frame(scenario: Scenario | None, points: Sequence[Sequence[float]]) -> MapFrame:
    """The view box around the scenario (or, without one, around the trajectory)."""
    if scenario is not None:
        (x0, x1), (y0, y1) = scenario.bounds.x, scenario.bounds.y
    elif points:
        xs, ys = [p[0] for p in points], [p[1] for p in points]
        x0, x1, y0, y1 = min(xs) - 1, max(xs) + 1, min(ys) - 1, max(ys) + 1
    else:
        x0, x1, y0, y1 = -5.0, 5.0, -5.0, 5.0
    m = MAP_MARGIN_M
    return MapFrame(round(x0 - m, 3), round(-(y1 + m), 3), round(x1 - x0 + 2 * m, 3), round(y1 - y0 + 2 * m, 3))


def shape_attrs(shape: Shape) -> dict[str, Any]:
    """SVG element name and attributes of a footprint (rotated rectangle or circle)."""
    cx, cy = svg_point(*shape.center)
    if shape.shape == "cylinder" and shape.radius is not None:
        return {"tag": "circle", "attrs": {"cx": cx, "cy": cy, "r": round(shape.radius, 3)}}
    sx, sy = shape.size or (0.1, 0.1)
    attrs: dict[str, Any] = {
        "x": round(cx - sx / 2, 3),
        "y": round(cy - sy / 2, 3),
        "width": round(sx, 3),
        "height": round(sy, 3),
    }
    if shape.yaw_deg:
        attrs["transform"] = f"rotate({-shape.yaw_deg:g} {cx:g} {cy:g})"  # y flipped: angles flip too
    return {"tag": "rect", "attrs": attrs}


def scenario_shapes(scenario: Scenario, added: Sequence[Sequence[float]] = ()) -> dict[str, Any]:
    """Corridors, walls, obstacles (plus boxes dropped at run time) and labelled objects."""
    from llmnav.baselines.oracle import with_added_obstacles

    world = with_added_obstacles(scenario, [(float(p[0]), float(p[1])) for p in added])
    corridors = [
        {
            "x": c.x[0],
            "y": -c.y[1],
            "width": round(c.x[1] - c.x[0], 3),
            "height": round(c.y[1] - c.y[0], 3),
            "id": c.id,
        }
        for c in world.corridors
    ]
    walls = [shape_attrs(w) for w in world.walls]
    obstacles = [{**shape_attrs(o), "fill": rgb(o.color), "id": o.id or "obstacle"} for o in world.obstacles]
    objects = []
    for obj in world.objects:
        lx, ly = svg_point(obj.center[0], obj.center[1] + obj.half_extents()[1])
        objects.append(
            {
                **shape_attrs(obj),
                "fill": rgb(obj.color),
                "solid": obj.solid,
                "label": obj.label,
                "id": obj.id,
                "label_x": lx,
                "label_y": ly,
            }
        )
    return {"corridors": corridors, "walls": walls, "obstacles": obstacles, "objects": objects}


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
