"""nav2 `map_server` maps (a YAML file and a PGM or PNG image) as llmnav worlds.

The map format (nav2 map_server / ROS map_server): `image` (path relative to the YAML file), `resolution`
[m/pixel], `origin` [x, y, yaw] of the lower-left pixel, `negate` (0/1), `occupied_thresh`, `free_thresh`,
`mode` (trinary by default, scale or raw). A pixel's occupancy probability is p = (255 - value) / 255, or
value / 255 with `negate` (alpha below 255 counts as unknown, as map_server reads it); p > occupied_thresh is
occupied, p < free_thresh free, anything else unknown (strict comparisons, as the ROS map_server documents;
scale mode's in-between values are unknown here too). In raw mode the value itself is the occupancy in
percent (0..100; above 100 is unknown), classified with the same thresholds.

The world: occupied and unknown cells are both solid (unknown space stays out of the robot's reach), merged
greedily into axis-aligned rectangles (runs of cells along a row, grown over the rows with the same run) so a
384 x 384 map becomes hundreds of boxes, not tens of thousands. The map's yaw turns every box about the
origin. An overlay file adds labelled objects, tasks and a default start; point tasks with start poses are
drawn on the free space, clear of everything solid, from a seed.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
import yaml
from pydantic import ValidationError

from llmnav.core.robot_specs import ROBOT_SPECS
from llmnav.core.safefiles import UnsafeFileError, read_bytes, write_text
from llmnav.errors import BadInputError, ScenarioError
from llmnav.mapping.grid import GridConfig
from llmnav.world.scenario import LabelledObject, Scenario, parse_scenario

MAX_YAML_BYTES = 1 << 20  # [bytes] a map YAML is a few lines; an overlay a few hundred
MAX_IMAGE_BYTES = 64 << 20  # [bytes] a 16-megapixel 8-bit PGM is 16 MB, an ASCII one up to ~64 MB
MAX_PIXELS = 16_000_000  # [px] 4000 x 4000 cells (200 m x 200 m at 0.05 m); checked before decoding
MAX_SIDE_PX = 20_000  # [px] one side
WALL_HEIGHT_M = 1.5  # [m] imported walls: above the LiDAR and most cameras' horizon
OCCUPIED_COLOR = (0.35, 0.35, 0.38, 1.0)
UNKNOWN_COLOR = (0.15, 0.15, 0.17, 1.0)
MIN_TASK_DISTANCE_M = 1.5  # [m] a drawn task's goal lies at least this far from its start
OVERLAY_KEYS = {"name", "description", "robot", "objects", "tasks", "default_start"}
Mode = Literal["trinary", "scale", "raw"]


@dataclass(frozen=True)
class MapSpec:
    """A nav2 map YAML, validated."""

    image: Path
    resolution: float  # [m/pixel]
    origin: tuple[float, float, float]  # [m, m, rad] pose of the lower-left pixel's corner
    negate: bool
    occupied_thresh: float
    free_thresh: float
    mode: Mode


@dataclass
class OccupancyMap:
    """Cells classified, row 0 = the image's bottom row (south), column 0 = west."""

    spec: MapSpec
    occupied: np.ndarray  # bool (rows, cols)
    free: np.ndarray  # bool (rows, cols); neither = unknown

    @property
    def solid(self) -> np.ndarray:
        """Cells the robot may not enter: occupied or unknown."""
        return ~self.free


def _load_yaml(path: Path, what: str) -> dict[str, Any]:
    try:
        text = read_bytes(path, limit=MAX_YAML_BYTES, root=path.parent, what=what).decode("utf-8")
    except FileNotFoundError:
        raise BadInputError(f"{what}: no such file") from None
    except UnicodeDecodeError:
        raise BadInputError(f"{what}: not UTF-8 text") from None
    except UnsafeFileError:
        raise
    except OSError as err:
        raise BadInputError(f"{what}: cannot read: {err.strerror or err}") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f"line {mark.line + 1}: " if mark is not None else ""
        raise BadInputError(f"{what}: {where}not valid YAML") from None
    if not isinstance(data, dict):
        raise BadInputError(f"{what}: expected a mapping of fields, got {type(data).__name__}")
    return data


def _number(data: dict[str, Any], key: str, what: str) -> float:
    value = data.get(key)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise BadInputError(f"{what}: '{key}' must be a finite number, got {value!r}")
    return float(value)


def read_map_yaml(path: Path) -> MapSpec:
    """Validate a map YAML's fields (the image is not read here)."""
    path = Path(path)
    what = str(path)
    data = _load_yaml(path, what)
    for key in ("image", "resolution", "origin", "occupied_thresh", "free_thresh"):
        if key not in data:
            raise BadInputError(f"{what}: missing '{key}'")
    image = data["image"]
    if not isinstance(image, str) or not image.strip():
        raise BadInputError(f"{what}: 'image' must be a file name, got {image!r}")
    resolution = _number(data, "resolution", what)
    if resolution <= 0:
        raise BadInputError(f"{what}: 'resolution' must be positive [m/pixel], got {resolution:g}")
    origin = data["origin"]
    if (
        not isinstance(origin, list)
        or len(origin) != 3
        or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in origin)
    ):
        raise BadInputError(f"{what}: 'origin' must be [x, y, yaw] as finite numbers, got {origin!r}")
    occupied, free = _number(data, "occupied_thresh", what), _number(data, "free_thresh", what)
    for key, value in (("occupied_thresh", occupied), ("free_thresh", free)):
        if not 0.0 <= value <= 1.0:
            raise BadInputError(f"{what}: '{key}' must lie in [0, 1], got {value:g}")
    if free >= occupied:
        raise BadInputError(f"{what}: 'free_thresh' ({free:g}) must be below 'occupied_thresh' ({occupied:g})")
    negate = data.get("negate", 0)
    if negate not in (0, 1) or isinstance(negate, float):
        raise BadInputError(f"{what}: 'negate' must be 0 or 1, got {negate!r}")
    mode = data.get("mode", "trinary")
    if mode not in ("trinary", "scale", "raw"):
        raise BadInputError(f"{what}: 'mode' must be trinary, scale or raw, got {mode!r}")
    image_path = Path(image) if Path(image).is_absolute() else path.parent / image
    return MapSpec(
        image=image_path,
        resolution=resolution,
        origin=(float(origin[0]), float(origin[1]), float(origin[2])),
        negate=bool(negate),
        occupied_thresh=occupied,
        free_thresh=free,
        mode=mode,
    )


# --- images --------------------------------------------------------------------------------------

_PGM_HEADER = re.compile(rb"\A(P[25])(?:\s+|#[^\n]*\n)+?(\d+)(?:\s+|#[^\n]*\n)+(\d+)(?:\s+|#[^\n]*\n)+(\d+)\s")


def _check_size(width: int, height: int, what: str) -> None:
    if width < 1 or height < 1:
        raise BadInputError(f"{what}: an empty image ({width} x {height})")
    if width > MAX_SIDE_PX or height > MAX_SIDE_PX or width * height > MAX_PIXELS:
        raise BadInputError(
            f"{what}: {width} x {height} pixels, over the cap of {MAX_PIXELS:,} pixels ({MAX_SIDE_PX:,} a side)"
        )


def _read_pgm(data: bytes, what: str) -> tuple[np.ndarray, int]:
    """(values as int array (rows, cols), maxval) of a binary (P5) or ASCII (P2) PGM."""
    match = _PGM_HEADER.match(data[:4096])
    if match is None:
        raise BadInputError(f"{what}: not a valid PGM header")
    kind, width, height, maxval = match.group(1), int(match.group(2)), int(match.group(3)), int(match.group(4))
    _check_size(width, height, what)
    if not 0 < maxval < 65536:
        raise BadInputError(f"{what}: PGM maxval must be 1..65535, got {maxval}")
    body = data[match.end() :]
    count = width * height
    if kind == b"P5":
        dtype = np.dtype(np.uint8) if maxval < 256 else np.dtype(">u2")
        if len(body) < count * dtype.itemsize:
            raise BadInputError(f"{what}: PGM data ends early ({len(body)} bytes for {width} x {height} pixels)")
        values = np.frombuffer(body, dtype=dtype, count=count).astype(np.int32)
    else:
        tokens = body.split()
        if len(tokens) < count:
            raise BadInputError(f"{what}: PGM data ends early ({len(tokens)} values for {width} x {height} pixels)")
        try:
            values = np.array(tokens[:count], dtype=np.int64).astype(np.int32)
        except ValueError:
            raise BadInputError(f"{what}: PGM values must be integers") from None
    if values.max(initial=0) > maxval:
        raise BadInputError(f"{what}: a PGM value exceeds maxval {maxval}")
    return values.reshape(height, width), maxval


def _read_png(data: bytes, what: str) -> tuple[np.ndarray, int, np.ndarray | None]:
    """(grey values (rows, cols), full scale, alpha or None) of a PNG; colour becomes luma like map_server's."""
    if len(data) < 24 or data[12:16] != b"IHDR":
        raise BadInputError(f"{what}: not a valid PNG header")
    width, height = int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    _check_size(width, height, what)
    # deferred: OpenCV (about 0.13 s) loads only when a PNG map is read
    import cv2

    image = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise BadInputError(f"{what}: the PNG cannot be decoded")
    scale = 65535 if image.dtype == np.uint16 else 255
    alpha = None
    if image.ndim == 3:
        if image.shape[2] == 4:
            alpha = image[:, :, 3].astype(np.int64) * 255 // scale
            image = image[:, :, :3]
        image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.shape[2] == 3 else image[:, :, 0]
    return image.astype(np.int32), scale, alpha


def read_occupancy(spec: MapSpec) -> OccupancyMap:
    """Read and classify the map's image (PGM or PNG, by content, not by name)."""
    what = str(spec.image)
    try:  # no links at all, no FIFOs or devices, at most MAX_IMAGE_BYTES
        data = read_bytes(spec.image, limit=MAX_IMAGE_BYTES, what=what)
    except FileNotFoundError:
        raise BadInputError(f"{what}: the image the map names does not exist") from None
    alpha = None
    if data[:2] in (b"P5", b"P2"):
        values, scale = _read_pgm(data, what)
    elif data.startswith(b"\x89PNG\r\n\x1a\n"):
        values, scale, alpha = _read_png(data, what)
    else:
        raise BadInputError(f"{what}: not a PGM or PNG image")
    if spec.mode == "raw":
        unknown_value = values > 100
        p = np.where(unknown_value, 0.5, values / 100.0)
    else:
        unknown_value = np.zeros(values.shape, dtype=bool)
        p = values / scale if spec.negate else (scale - values) / scale
        if alpha is not None:
            unknown_value |= alpha < 255
    occupied = (p > spec.occupied_thresh) & ~unknown_value
    free = (p < spec.free_thresh) & ~unknown_value
    # image row 0 is the top (north): flip so that row 0 is the south edge, as in the world and OccupancyGrid
    return OccupancyMap(spec, np.flipud(occupied), np.flipud(free))


# --- the world -----------------------------------------------------------------------------------


def merge_rectangles(mask: np.ndarray) -> list[tuple[int, int, int, int]]:
    """Cover the True cells exactly with disjoint rectangles (row0, col0, row1, col1), ends exclusive.

    Greedy, along rows and along columns, keeping whichever needs fewer rectangles (columns saved 9 % of
    the boxes on nav2's depot map, whose walls are speckled).
    """
    by_rows = _merge_runs(mask)
    by_cols = [(r0, c0, r1, c1) for c0, r0, c1, r1 in _merge_runs(mask.T)]
    return by_cols if len(by_cols) < len(by_rows) else by_rows


def _merge_runs(mask: np.ndarray) -> list[tuple[int, int, int, int]]:
    """Each row's runs of uncovered cells, each grown over the following rows while they repeat it."""
    rows, cols = mask.shape
    covered = np.zeros_like(mask, dtype=bool)
    rectangles: list[tuple[int, int, int, int]] = []
    for r in range(rows):
        line = mask[r] & ~covered[r]
        if not line.any():
            continue
        edges = np.flatnonzero(np.diff(np.concatenate(([0], line.astype(np.int8), [0]))))
        for c0, c1 in zip(edges[::2], edges[1::2], strict=True):
            r1 = r + 1
            while r1 < rows and mask[r1, c0:c1].all() and not covered[r1, c0:c1].any():
                r1 += 1
            covered[r:r1, c0:c1] = True
            rectangles.append((r, int(c0), r1, int(c1)))
    return rectangles


def _to_world(spec: MapSpec, x: float, y: float) -> tuple[float, float]:
    """A point in the map's own frame (lower-left corner at 0, 0) in the world frame."""
    ox, oy, yaw = spec.origin
    c, s = math.cos(yaw), math.sin(yaw)
    return (ox + c * x - s * y, oy + s * x + c * y)


def _walls(grid: OccupancyMap) -> list[dict[str, Any]]:
    spec, res = grid.spec, grid.spec.resolution
    walls = []
    kinds = (("occupied", grid.occupied, OCCUPIED_COLOR), ("unknown", grid.solid & ~grid.occupied, UNKNOWN_COLOR))
    for kind, mask, color in kinds:
        for i, (r0, c0, r1, c1) in enumerate(merge_rectangles(mask)):
            cx, cy = _to_world(spec, (c0 + c1) / 2 * res, (r0 + r1) / 2 * res)
            wall: dict[str, Any] = {
                "id": f"{kind}-{i}",
                "center": [round(cx, 4), round(cy, 4)],
                "size": [round((c1 - c0) * res, 4), round((r1 - r0) * res, 4)],
                "height": WALL_HEIGHT_M,
                "color": list(color),
            }
            if spec.origin[2] != 0.0:
                wall["yaw_deg"] = round(math.degrees(spec.origin[2]), 6)
            walls.append(wall)
    return walls


def _bounds(grid: OccupancyMap) -> dict[str, list[float]]:
    rows, cols = grid.free.shape
    res = grid.spec.resolution
    corners = [_to_world(grid.spec, x, y) for x in (0.0, cols * res) for y in (0.0, rows * res)]
    xs, ys = [c[0] for c in corners], [c[1] for c in corners]
    return {"x": [round(min(xs), 4), round(max(xs), 4)], "y": [round(min(ys), 4), round(max(ys), 4)]}


def _read_overlay(path: Path) -> dict[str, Any]:
    data = _load_yaml(path, str(path))
    unknown = sorted(set(data) - OVERLAY_KEYS)
    if unknown:
        raise BadInputError(f"{path}: unknown field '{unknown[0]}' (known: {', '.join(sorted(OVERLAY_KEYS))})")
    objects = data.get("objects", [])
    if not isinstance(objects, list) or not all(isinstance(o, dict) for o in objects):
        raise BadInputError(f"{path}: 'objects' must be a list of mappings")
    renamed = []
    for i, obj in enumerate(objects):  # `position` is the overlay's word for a shape's `center`
        if "position" in obj and "center" in obj:
            raise BadInputError(f"{path}: objects[{i}]: give 'position' or 'center', not both")
        renamed.append({("center" if k == "position" else k): v for k, v in obj.items()})
    data["objects"] = renamed
    return data


def _clear_cells(grid: OccupancyMap, clearance_m: float) -> np.ndarray:
    """Free cells at least `clearance_m` [m] from every solid cell, in the largest 4-connected such region."""
    # deferred: scipy.ndimage (about 0.3 s) loads only when clearance is computed
    from scipy import ndimage

    distance = ndimage.distance_transform_edt(grid.free) * grid.spec.resolution  # [m] to the nearest solid cell
    clear = distance >= clearance_m
    labels, count = ndimage.label(clear)
    if count == 0:
        return clear
    sizes = np.bincount(labels.ravel())
    sizes[0] = 0
    return labels == int(np.argmax(sizes))


def _draw_tasks(
    grid: OccupancyMap, robot: str, solids: list[Any], count: int, seed: int, first: int
) -> list[dict[str, Any]]:
    """`count` point tasks with one start pose each, on clear free space, reachable from one another."""
    spec = ROBOT_SPECS[robot]
    res = grid.spec.resolution
    clearance = spec.radius_m + GridConfig().margin_m + 2 * res  # [m] the oracle's inflation and two cells
    clear = _clear_cells(grid, clearance)
    rows, cols = np.nonzero(clear)
    if count and len(rows) < 2:
        raise BadInputError(
            f"{grid.spec.image}: no free space {clearance:.2f} m clear of walls for a {robot} to start and stop in"
        )
    rng = np.random.default_rng(seed)

    def point(i: int) -> tuple[float, float]:
        return _to_world(grid.spec, (float(cols[i]) + 0.5) * res, (float(rows[i]) + 0.5) * res)

    def clear_of_objects(x: float, y: float) -> bool:
        return not any(s.contains(x, y, inflate=clearance) for s in solids)

    tasks: list[dict[str, Any]] = []
    for _ in range(200 * max(count, 1)):
        if len(tasks) == count:
            break
        start, goal = point(int(rng.integers(len(rows)))), point(int(rng.integers(len(rows))))
        if math.dist(start, goal) < MIN_TASK_DISTANCE_M or not (clear_of_objects(*start) and clear_of_objects(*goal)):
            continue
        x, y = round(goal[0], 3), round(goal[1], 3)
        tasks.append(
            {
                "id": f"P{first + len(tasks)}",
                "text": f"Go to the point ({x:g}, {y:g})",
                "targets": [{"point": [x, y]}],
                "start_poses": [
                    {"x": round(start[0], 3), "y": round(start[1], 3), "yaw_deg": round(float(rng.uniform(-180, 180)))}
                ],
            }
        )
    if len(tasks) < count:
        raise BadInputError(f"{grid.spec.image}: could not place {count} tasks at least {MIN_TASK_DISTANCE_M} m long")
    return tasks


def _objects(objects: list[dict[str, Any]], source: str) -> list[LabelledObject]:
    """The overlay's objects, validated one by one (the whole world is validated once it is complete)."""
    validated = []
    for i, obj in enumerate(objects):
        try:
            validated.append(LabelledObject.model_validate(obj))
        except ValidationError as err:
            first = err.errors()[0]
            where = ".".join(str(part) for part in first["loc"])
            problem = first["msg"].removeprefix("Value error, ")
            raise BadInputError(f"{source}: objects[{i}]{'.' + where if where else ''}: {problem}") from None
    return validated


@dataclass
class ImportResult:
    """What an import built."""

    scenario: Scenario
    data: dict[str, Any]  # the scenario as written
    walls: int
    size_px: tuple[int, int]  # (width, height)


def import_map(
    map_yaml: Path, *, overlay: Path | None = None, robot: str = "burger", tasks: int = 5, seed: int = 0
) -> ImportResult:
    """Build (and validate) a scenario from a nav2 map; nothing is written."""
    if robot not in ROBOT_SPECS:
        raise BadInputError(f"unknown robot '{robot}' (known: {', '.join(sorted(ROBOT_SPECS))})")
    if not 0 <= tasks <= 1000:
        raise BadInputError(f"--tasks must be 0..1000, got {tasks}")
    spec = read_map_yaml(Path(map_yaml))
    extra = _read_overlay(Path(overlay)) if overlay is not None else {}
    grid = read_occupancy(spec)
    robot = str(extra.get("robot", robot))
    walls = _walls(grid)
    data: dict[str, Any] = {
        "name": extra.get("name", Path(map_yaml).stem),
        "description": extra.get(
            "description",
            f"imported from the nav2 map {Path(map_yaml).name} ({grid.free.shape[1]} x {grid.free.shape[0]} cells "
            f"at {spec.resolution:g} m); unknown space is solid",
        ),
        "robot": robot,
        "bounds": _bounds(grid),
        "walls": walls,
        "objects": extra.get("objects", []),
        "tasks": list(extra.get("tasks", [])),
        "default_information": "map",
    }
    source = str(overlay or map_yaml)
    solids = [o for o in _objects(data["objects"], source) if o.solid]  # drawn tasks keep clear of them
    drawn = _draw_tasks(grid, robot, solids, tasks, seed, 1)
    data["tasks"] = data["tasks"] + drawn
    if "default_start" in extra:
        data["default_start"] = extra["default_start"]
    elif data["tasks"] and data["tasks"][0].get("start_poses"):
        first = data["tasks"][0]["start_poses"][0]
        data["default_start"] = {k: first[k] for k in ("x", "y", "yaw_deg") if k in first}
    elif drawn:
        data["default_start"] = drawn[0]["start_poses"][0]
    try:
        scenario = parse_scenario(data, source)
    except ScenarioError as err:
        raise BadInputError(str(err)) from None
    if not scenario.tasks and "default_start" not in data:
        raise BadInputError(f"{source}: no tasks and no default start; give --tasks N or an overlay with tasks")
    return ImportResult(scenario, data, len(walls), (grid.free.shape[1], grid.free.shape[0]))


def write_world(result: ImportResult, out: Path, map_yaml: Path) -> Path:
    """Write the scenario YAML (atomically); the header says where it came from."""
    header = (
        f"# A world imported from the nav2 map {Path(map_yaml).name} by `llmnav scenarios import-map`:\n"
        f"# {result.size_px[0]} x {result.size_px[1]} cells, {result.walls} wall boxes "
        "(occupied and unknown cells, both solid).\n"
    )
    text = header + yaml.safe_dump(result.data, sort_keys=False, default_flow_style=None, width=120)
    try:
        return write_text(Path(out), text)
    except OSError as err:
        raise BadInputError(f"cannot write {out}: {err.strerror or err}") from None
