"""An llmnav world as a nav2 `map_server` map (YAML + PGM), so nav2 can load it.

Every solid shape the robot cannot pass under is rasterised: a cell is occupied when its centre lies inside
a shape (so the boxes `mapimport` made from cells come back as exactly those cells). The image is trinary,
not negated: 0 (black) occupied, 254 free; nothing is unknown. The origin is the world bounds' lower-left
corner, with yaw 0.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import yaml

from llmnav.core.robot_specs import ROBOT_SPECS
from llmnav.core.safefiles import write_bytes, write_text
from llmnav.errors import BadInputError
from llmnav.mapping.grid import GridGeometry, shape_distance
from llmnav.world.scenario import Scenario

OCCUPIED_VALUE = 0  # p = 1.0
FREE_VALUE = 254  # p = 0.004, as map_saver writes free cells
OCCUPIED_THRESH = 0.65  # map_saver's defaults for a trinary map
FREE_THRESH = 0.25
MAX_CELLS = 16_000_000  # the import's own cap: what is written can be read back


def occupancy(scenario: Scenario, resolution_m: float) -> tuple[GridGeometry, np.ndarray]:
    """Cells (row 0 = south) whose centre lies inside a solid shape lower than the robot."""
    geometry = GridGeometry.from_bounds(scenario.bounds, resolution_m)
    if geometry.rows * geometry.cols > MAX_CELLS:
        raise BadInputError(
            f"{scenario.name}: {geometry.cols} x {geometry.rows} cells at {resolution_m:g} m, over {MAX_CELLS:,}"
        )
    robot = ROBOT_SPECS[scenario.robot]
    occupied = np.zeros(geometry.shape, dtype=bool)
    res = geometry.resolution
    for shape in scenario.solid_shapes():
        if shape.z >= robot.height_m:
            continue
        half_x, half_y = shape.half_extents()
        col0 = max(0, math.floor((shape.center[0] - half_x - geometry.origin_x) / res))
        col1 = min(geometry.cols, math.ceil((shape.center[0] + half_x - geometry.origin_x) / res) + 1)
        row0 = max(0, math.floor((shape.center[1] - half_y - geometry.origin_y) / res))
        row1 = min(geometry.rows, math.ceil((shape.center[1] + half_y - geometry.origin_y) / res) + 1)
        if col0 < col1 and row0 < row1:
            xs, ys = geometry.centres(slice(row0, row1), slice(col0, col1))
            occupied[row0:row1, col0:col1] |= shape_distance(shape, xs, ys) <= 0.0
    return geometry, occupied


def export_map(scenario: Scenario, out_yaml: Path, resolution_m: float = 0.05) -> tuple[Path, Path]:
    """Write OUT.yaml and OUT.pgm beside it; BadInputError if either exists or the grid is too large."""
    if not (math.isfinite(resolution_m) and resolution_m > 0):
        raise BadInputError(f"--resolution must be a positive number of metres, got {resolution_m:g}")
    out_yaml = Path(out_yaml)
    image = out_yaml.with_suffix(".pgm")
    for path in (out_yaml, image):
        if path.exists() or path.is_symlink():
            raise BadInputError(f"{path} already exists; choose another name (nothing is overwritten)")
    geometry, occupied = occupancy(scenario, resolution_m)
    pixels = np.where(np.flipud(occupied), OCCUPIED_VALUE, FREE_VALUE).astype(np.uint8)  # image rows: north first
    header = f"P5\n# llmnav world {scenario.name}\n{geometry.cols} {geometry.rows}\n255\n".encode()
    spec = {
        "image": image.name,
        "mode": "trinary",
        "resolution": resolution_m,
        "origin": [geometry.origin_x, geometry.origin_y, 0.0],
        "negate": 0,
        "occupied_thresh": OCCUPIED_THRESH,
        "free_thresh": FREE_THRESH,
    }
    try:
        write_bytes(image, header + pixels.tobytes())
        write_text(out_yaml, yaml.safe_dump(spec, sort_keys=False, default_flow_style=None))
    except OSError as err:
        raise BadInputError(f"cannot write {out_yaml}: {err.strerror or err}") from None
    return out_yaml, image
