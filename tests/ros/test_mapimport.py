"""`llmnav scenarios import-map`: nav2 map_server maps as worlds, on drawn maps and on real published ones.

Expected occupancy comes from the map format's own rule, written out here (p = (255 - v) / 255, or v / 255
with negate; p > occupied_thresh occupied, p < free_thresh free, else unknown) and from the PGM bytes read
with numpy, never from the importer.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from llmnav.cli import app
from llmnav.planners.base import drive_options
from llmnav.ros.mapimport import merge_rectangles
from llmnav.runs.runner import EpisodeSpec, run_episode
from llmnav.world.scenario import Scenario, load_scenario

runner = CliRunner()
MAPS = Path(__file__).parents[1] / "data" / "maps"
TB3 = MAPS / "turtlebot3_world" / "map.yaml"
DEPOT = MAPS / "nav2_depot" / "depot.yaml"


def _pgm(path: Path, pixels: np.ndarray) -> None:
    """A binary PGM, rows top to bottom as images store them."""
    height, width = pixels.shape
    path.write_bytes(f"P5\n# drawn for a test\n{width} {height}\n255\n".encode() + pixels.astype(np.uint8).tobytes())


def _read_pgm(path: Path) -> np.ndarray:
    """A P5 PGM's pixels (the real maps: one comment line, 8-bit)."""
    data = path.read_bytes()
    lines = data.split(b"\n", 4)
    header = [line for line in lines[:4] if not line.startswith(b"#")]
    assert header[0] == b"P5" and header[2] == b"255"
    width, height = (int(v) for v in header[1].split())
    return np.frombuffer(data[len(data) - width * height :], dtype=np.uint8).reshape(height, width)


def _map_yaml(folder: Path, image: str = "m.pgm", **fields: Any) -> Path:
    data = {
        "image": image,
        "resolution": 0.5,
        "origin": [-1.0, 2.0, 0.0],
        "negate": 0,
        "occupied_thresh": 0.65,
        "free_thresh": 0.2,
        **fields,
    }
    path = folder / "m.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def _import(map_yaml: Path, out: Path, *extra: str) -> Any:
    return runner.invoke(app, ["scenarios", "import-map", str(map_yaml), "-o", str(out), *extra])


def _solid_cells(scenario: Scenario, shape: tuple[int, int], origin: tuple[float, float], res: float) -> np.ndarray:
    """Which cells (row 0 = south) have their centre inside one of the world's walls."""
    rows, cols = shape
    solid = np.zeros(shape, dtype=bool)
    for r in range(rows):
        for c in range(cols):
            x, y = origin[0] + (c + 0.5) * res, origin[1] + (r + 0.5) * res
            solid[r, c] = any(w.contains(x, y) for w in scenario.walls)
    return solid


def _expected_solid(pixels: np.ndarray, negate: bool, occupied: float, free: float) -> np.ndarray:
    p = pixels / 255.0 if negate else (255 - pixels) / 255.0
    is_free = p < free
    assert ((p > occupied) & is_free).sum() == 0
    return np.flipud(~is_free)  # row 0 = south


# A drawn 5 x 8 map: values straddling both thresholds (p of 0.65 and 0.2 are v = 89.25 and 204)
PIXELS = np.array(
    [
        [0, 0, 0, 0, 0, 0, 0, 0],
        [0, 254, 254, 205, 203, 254, 90, 0],
        [0, 254, 89, 89, 254, 254, 254, 0],
        [0, 204, 254, 254, 254, 250, 254, 0],
        [0, 0, 0, 0, 0, 0, 0, 0],
    ]
)


@pytest.mark.parametrize("negate", [0, 1])
def test_trinary_thresholds_negate_origin_and_resolution(tmp_path: Path, negate: int) -> None:
    pixels = PIXELS if not negate else 255 - PIXELS
    _pgm(tmp_path / "m.pgm", pixels)
    overlay = tmp_path / "o.yaml"  # no tasks drawn on so small a map: the overlay gives the start
    overlay.write_text(yaml.safe_dump({"default_start": {"x": 0.75, "y": 3.75}}))  # cell row 3 (from south), col 3
    result = _import(_map_yaml(tmp_path, negate=negate), tmp_path / "w.yaml", "--tasks", "0", "--objects", str(overlay))
    assert result.exit_code == 0, result.output
    scenario = load_scenario(tmp_path / "w.yaml")
    assert scenario.bounds.x == (-1.0, 3.0) and scenario.bounds.y == (2.0, 4.5)
    got = _solid_cells(scenario, PIXELS.shape, (-1.0, 2.0), 0.5)
    want = _expected_solid(pixels, bool(negate), 0.65, 0.2)
    assert (got == want).all()
    # 205 (p 0.196) is free; 204 (p 0.2 exactly) is not, the comparison being strict; nor is 203 (p 0.204)
    assert not want[3, 3] and want[1, 1] and want[3, 4]
    assert len(scenario.walls) < int(want.sum())  # merged


def test_walls_are_occupied_and_unknown_boxes_of_their_kind(tmp_path: Path) -> None:
    pixels = np.full((4, 6), 254)
    pixels[0, :] = 0  # occupied (north row)
    pixels[3, :] = 180  # unknown (south row): p 0.29, between the thresholds
    _pgm(tmp_path / "m.pgm", pixels)
    overlay = tmp_path / "o.yaml"
    overlay.write_text(yaml.safe_dump({"default_start": {"x": 0.25, "y": 3.25}}))
    result = _import(_map_yaml(tmp_path), tmp_path / "w.yaml", "--tasks", "0", "--objects", str(overlay))
    assert result.exit_code == 0, result.output
    scenario = load_scenario(tmp_path / "w.yaml")
    kinds = sorted((w.id or "").split("-")[0] for w in scenario.walls)
    assert kinds == ["occupied", "unknown"]  # each row is one box
    north = next(w for w in scenario.walls if (w.id or "").startswith("occupied"))
    assert north.center == (0.5, 3.75) and north.size == (3.0, 0.5)


def test_scale_and_raw_modes(tmp_path: Path) -> None:
    pixels = np.array([[254, 150, 0, 254]])  # p = 0.004, 0.41, 1.0, 0.004
    _pgm(tmp_path / "m.pgm", pixels)
    overlay = tmp_path / "o.yaml"
    overlay.write_text(yaml.safe_dump({"default_start": {"x": -0.75, "y": 2.25}}))
    result = _import(_map_yaml(tmp_path, mode="scale"), tmp_path / "s.yaml", "--tasks", "0", "--objects", str(overlay))
    assert result.exit_code == 0, result.output
    got = _solid_cells(load_scenario(tmp_path / "s.yaml"), (1, 4), (-1.0, 2.0), 0.5)
    assert got.tolist() == [[False, True, True, False]]  # in between (0.41) counts as unknown: solid
    raw = np.array([[0, 50, 100, 255]])  # occupancy in percent; above 100 unknown
    _pgm(tmp_path / "m.pgm", raw)
    result = _import(_map_yaml(tmp_path, mode="raw"), tmp_path / "r.yaml", "--tasks", "0", "--objects", str(overlay))
    assert result.exit_code == 0, result.output
    got = _solid_cells(load_scenario(tmp_path / "r.yaml"), (1, 4), (-1.0, 2.0), 0.5)
    assert got.tolist() == [[False, True, True, True]]


def test_png_with_alpha_and_colour(tmp_path: Path) -> None:
    bgra = np.zeros((2, 3, 4), dtype=np.uint8)
    bgra[:, :, :3] = 255  # white: free
    bgra[:, :, 3] = 255
    bgra[0, 2, 3] = 0  # transparent: unknown
    bgra[1, 0, :3] = 0  # black: occupied
    assert cv2.imwrite(str(tmp_path / "m.png"), bgra)
    overlay = tmp_path / "o.yaml"
    overlay.write_text(yaml.safe_dump({"default_start": {"x": 0.25, "y": 2.25}}))
    result = _import(_map_yaml(tmp_path, image="m.png"), tmp_path / "w.yaml", "--tasks", "0", "--objects", str(overlay))
    assert result.exit_code == 0, result.output
    got = _solid_cells(load_scenario(tmp_path / "w.yaml"), (2, 3), (-1.0, 2.0), 0.5)
    assert got.tolist() == [[True, False, False], [False, False, True]]  # row 0 = south = the image's bottom


def test_origin_yaw_turns_the_map_about_its_origin(tmp_path: Path) -> None:
    pixels = np.full((3, 5), 254)
    pixels[2, 4] = 0  # the bottom-right cell: 2.25 m east of the origin along the map's x axis
    _pgm(tmp_path / "m.pgm", pixels)
    overlay = tmp_path / "o.yaml"
    overlay.write_text(yaml.safe_dump({"default_start": {"x": -1.25, "y": 2.75}}))
    yaml_path = _map_yaml(tmp_path, origin=[1.0, 2.0, math.pi / 2])
    result = _import(yaml_path, tmp_path / "w.yaml", "--tasks", "0", "--objects", str(overlay))
    assert result.exit_code == 0, result.output
    scenario = load_scenario(tmp_path / "w.yaml")
    # turned 90°: the map's +x is the world's +y, so that cell's centre is at (1 - 0.25, 2 + 2.25)
    occupied = [w for w in scenario.walls if (w.id or "").startswith("occupied")]
    assert len(occupied) == 1 and occupied[0].contains(0.75, 4.25) and not occupied[0].contains(3.25, 2.25)
    assert math.isclose(occupied[0].yaw_deg, 90.0)
    assert math.isclose(scenario.bounds.x[0], -0.5) and math.isclose(scenario.bounds.y[1], 4.5)


@pytest.mark.parametrize("seed", range(5))
def test_merged_rectangles_cover_the_cells_exactly_once(seed: int) -> None:
    rng = np.random.default_rng(seed)
    mask = rng.random((40, 60)) < 0.5
    mask[10:30, 5:50] = True  # a big block: merged into few boxes
    count = np.zeros(mask.shape, dtype=int)
    rectangles = merge_rectangles(mask)
    for r0, c0, r1, c1 in rectangles:
        count[r0:r1, c0:c1] += 1
    assert (count == mask.astype(int)).all()
    assert len(rectangles) < mask.sum() / 2


def _drive(world: Path, task: str, out: Path, robot_run: str = "oracle") -> dict[str, Any]:
    spec = EpisodeSpec(
        scenario=str(world), task_id=task, options=drive_options(planner=robot_run), out_dir=out, plots=False
    )
    return run_episode(spec)


# The depot's 1,200 static boxes make each physics step ~2 ms (a drive there takes 10-60 s on a loaded
# machine): its drives are in the slow test below; the TurtleBot3 world drives four tasks here.
REAL = [(TB3, "burger", 4), (DEPOT, "pr2", 0)]


@pytest.mark.parametrize(("map_yaml", "robot", "tasks"), REAL, ids=["turtlebot3_world", "depot"])
def test_real_map_imports_and_the_oracle_reaches_drawn_points(
    tmp_path: Path, map_yaml: Path, robot: str, tasks: int
) -> None:
    world = tmp_path / "world.yaml"
    result = _import(map_yaml, world, "--robot", robot, "--tasks", str(max(tasks, 1)), "--seed", "3")
    assert result.exit_code == 0, result.output
    spec = yaml.safe_load(map_yaml.read_text())
    pixels = _read_pgm(map_yaml.parent / spec["image"])
    scenario = load_scenario(world)
    want = _expected_solid(pixels, False, spec["occupied_thresh"], spec["free_thresh"])
    res = spec["resolution"]
    wall_cells = sum(w.size[0] * w.size[1] for w in scenario.walls if w.size) / res**2  # type: ignore[index]
    assert round(wall_cells) == int(want.sum())  # the boxes cover as many cells as the image marks solid
    assert len(scenario.walls) < want.sum() / 4  # merged (the depot's speckled walls merge least: 4.5 cells a box)
    for task in scenario.tasks[:tasks]:
        summary = _drive(world, task.id, tmp_path / task.id)
        assert summary["success"] and summary["collisions"] == 0, (task.id, summary["reason"])


@pytest.mark.slow
@pytest.mark.parametrize(("map_yaml", "robot"), [(TB3, "burger"), (DEPOT, "pr2")], ids=["turtlebot3_world", "depot"])
def test_oracle_succeeds_on_95_percent_of_30_drawn_tasks(tmp_path: Path, map_yaml: Path, robot: str) -> None:
    world = tmp_path / "world.yaml"
    assert _import(map_yaml, world, "--robot", robot, "--tasks", "30", "--seed", "11").exit_code == 0
    results = [_drive(world, task.id, tmp_path / task.id) for task in load_scenario(world).tasks]
    assert len(results) == 30
    assert sum(r["success"] for r in results) >= 0.95 * 30
    assert all(r["collisions"] == 0 for r in results)


def test_overlay_objects_and_tasks(tmp_path: Path) -> None:
    overlay = tmp_path / "overlay.yaml"
    overlay.write_text(
        yaml.safe_dump(
            {
                "name": "tb3_with_crate",
                "objects": [
                    {"id": "C1", "label": "crate", "aliases": ["box"], "position": [0.55, -0.55], "size": [0.2, 0.2]}
                ],
                "tasks": [
                    {
                        "id": "T1",
                        "text": "Go to the crate",
                        "targets": [{"object": "C1"}],
                        "start_poses": [{"x": -1.65, "y": 0.55, "yaw_deg": 0}],
                    }
                ],
            }
        )
    )
    world = tmp_path / "world.yaml"
    result = _import(TB3, world, "--objects", str(overlay), "--tasks", "2")
    assert result.exit_code == 0, result.output
    scenario = load_scenario(world)
    assert scenario.name == "tb3_with_crate"
    assert scenario.object("C1").label == "crate" and scenario.object("C1").center == (0.55, -0.55)
    assert [t.id for t in scenario.tasks] == ["T1", "P1", "P2"]
    for task in scenario.tasks[1:]:  # drawn points keep clear of the crate
        assert all(not scenario.object("C1").contains(*p, inflate=0.2) for p in scenario.target_points(task))
    summary = _drive(world, "T1", tmp_path / "run")
    assert summary["success"] and summary["collisions"] == 0, summary["reason"]


def test_drawn_tasks_depend_on_the_seed(tmp_path: Path) -> None:
    texts = []
    for seed in ("1", "1", "2"):
        out = tmp_path / f"w{len(texts)}.yaml"
        assert _import(TB3, out, "--seed", seed, "--tasks", "3").exit_code == 0
        texts.append([t.text for t in load_scenario(out).tasks])
    assert texts[0] == texts[1] != texts[2]


def _huge(folder: Path) -> None:
    (folder / "m.pgm").write_bytes(b"P5\n100000 100000\n255\n" + b"\0" * 64)


def _link(folder: Path) -> None:
    _pgm(folder / "real.pgm", PIXELS)
    (folder / "m.pgm").symlink_to(folder / "real.pgm")


def _fifo(folder: Path) -> None:
    os.mkfifo(folder / "m.pgm")


BAD = [
    ("missing image", {}, None, "does not exist"),
    ("not pgm or png", {}, lambda f: (f / "m.pgm").write_bytes(b"\xff\xd8\xff\xe0 a jpeg"), "not a PGM or PNG"),
    ("negative resolution", {"resolution": -0.05}, "pgm", "'resolution' must be positive"),
    ("text resolution", {"resolution": "fine"}, "pgm", "'resolution' must be a finite number"),
    ("threshold above 1", {"occupied_thresh": 1.5}, "pgm", "must lie in [0, 1]"),
    ("threshold below 0", {"free_thresh": -0.1}, "pgm", "must lie in [0, 1]"),
    ("free above occupied", {"free_thresh": 0.7}, "pgm", "must be below"),
    ("bad negate", {"negate": 2}, "pgm", "'negate' must be 0 or 1"),
    ("bad mode", {"mode": "binary"}, "pgm", "'mode' must be trinary, scale or raw"),
    ("short origin", {"origin": [0, 0]}, "pgm", "'origin' must be [x, y, yaw]"),
    ("huge image", {}, _huge, "over the cap"),
    ("symlinked image", {}, _link, "symbolic link"),
    ("fifo image", {}, _fifo, "not a regular file"),
    ("truncated pgm", {}, lambda f: (f / "m.pgm").write_bytes(b"P5\n10 10\n255\n" + b"\0" * 20), "ends early"),
]


@pytest.mark.parametrize(("case", "fields", "make", "words"), BAD, ids=[b[0] for b in BAD])
def test_bad_maps_are_one_line_exit_2_and_write_nothing(
    tmp_path: Path, case: str, fields: dict, make: Any, words: str
) -> None:
    if make == "pgm":
        _pgm(tmp_path / "m.pgm", PIXELS)
    elif make is not None:
        make(tmp_path)
    out = tmp_path / "out" / "w.yaml"
    out.parent.mkdir()
    result = _import(_map_yaml(tmp_path, **fields), out)
    assert result.exit_code == 2, (case, result.output)
    assert words in result.stderr and len(result.stderr.strip().splitlines()) == 1, result.stderr
    assert not any(out.parent.iterdir())


def test_an_existing_world_file_is_not_overwritten(tmp_path: Path) -> None:
    out = tmp_path / "w.yaml"
    out.write_text("mine")
    result = _import(TB3, out)
    assert result.exit_code == 2 and "already exists" in result.stderr
    assert out.read_text() == "mine"


def test_an_overlay_with_an_unknown_field_or_bad_object_is_refused(tmp_path: Path) -> None:
    for data, words in (
        ({"walls": []}, "unknown field 'walls'"),
        ({"objects": [{"id": "C1", "label": "crate", "position": [0.5, 0.5]}]}, "objects[0]"),
        ({"objects": [{"id": "C1", "label": "crate", "position": [50.0, 0.5], "size": [1, 1]}]}, "outside bounds"),
    ):
        overlay = tmp_path / "o.yaml"
        overlay.write_text(yaml.safe_dump(data))
        out = tmp_path / "w.yaml"
        result = _import(TB3, out, "--objects", str(overlay))
        assert result.exit_code == 2 and words in result.stderr, result.stderr
        assert len(result.stderr.strip().splitlines()) == 1 and not out.exists()


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / (a | b).sum())


def test_import_export_round_trip_keeps_the_occupancy(tmp_path: Path) -> None:
    world = tmp_path / "world.yaml"
    assert _import(TB3, world).exit_code == 0
    result = runner.invoke(app, ["scenarios", "export-map", str(world), "-o", str(tmp_path / "back.yaml")])
    assert result.exit_code == 0, result.output
    back = yaml.safe_load((tmp_path / "back.yaml").read_text())
    assert back["image"] == "back.pgm" and back["resolution"] == 0.05 and back["origin"] == [-10.0, -10.0, 0.0]
    spec = yaml.safe_load(TB3.read_text())
    original = _expected_solid(
        _read_pgm(TB3.parent / spec["image"]), False, spec["occupied_thresh"], spec["free_thresh"]
    )
    exported = _read_pgm(tmp_path / "back.pgm")
    assert set(np.unique(exported)) <= {0, 254}
    assert _iou(np.flipud(exported == 0), original) >= 0.98  # unknown comes back as occupied: solid either way
    # and a world drawn by hand: factory -> map -> world -> map
    assert runner.invoke(app, ["scenarios", "export-map", "factory", "-o", str(tmp_path / "f.yaml")]).exit_code == 0
    assert _import(tmp_path / "f.yaml", tmp_path / "fw.yaml", "--robot", "pr2").exit_code == 0
    assert runner.invoke(app, ["scenarios", "export-map", str(tmp_path / "fw.yaml"), "-o", str(tmp_path / "f2.yaml")])
    first, second = _read_pgm(tmp_path / "f.pgm") == 0, _read_pgm(tmp_path / "f2.pgm") == 0
    assert first.shape == second.shape and first.sum() > 1000
    assert _iou(first, second) >= 0.98


def test_export_map_refuses_to_overwrite(tmp_path: Path) -> None:
    (tmp_path / "m.pgm").write_bytes(b"mine")
    result = runner.invoke(app, ["scenarios", "export-map", "factory", "-o", str(tmp_path / "m.yaml")])
    assert result.exit_code == 2 and "already exists" in result.stderr
    assert (tmp_path / "m.pgm").read_bytes() == b"mine" and not (tmp_path / "m.yaml").exists()


def test_ascii_and_16_bit_pgm_read_like_the_binary_one(tmp_path: Path) -> None:
    overlay = tmp_path / "o.yaml"
    overlay.write_text(yaml.safe_dump({"default_start": {"x": 0.75, "y": 3.75}}))
    height, width = PIXELS.shape
    ascii_pgm = f"P2\n{width} {height}\n255\n" + "\n".join(" ".join(str(v) for v in row) for row in PIXELS) + "\n"
    wide = (PIXELS.astype(np.uint32) * 257).astype(">u2")  # the same grey levels on a 0..65535 scale
    files = {"ascii.pgm": ascii_pgm.encode(), "wide.pgm": f"P5\n{width} {height}\n65535\n".encode() + wide.tobytes()}
    want = _expected_solid(PIXELS, False, 0.65, 0.2)
    for name, data in files.items():
        (tmp_path / name).write_bytes(data)
        out = tmp_path / f"{name}.yaml"
        result = _import(_map_yaml(tmp_path, image=name), out, "--tasks", "0", "--objects", str(overlay))
        assert result.exit_code == 0, result.output
        assert (_solid_cells(load_scenario(out), PIXELS.shape, (-1.0, 2.0), 0.5) == want).all(), name
