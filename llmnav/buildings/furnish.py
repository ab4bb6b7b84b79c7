"""Furnishing: the third step of ProcTHOR's recipe, objects placed room by room from the room type's list.

Each slot of a room type asks for a number of catalogue items; each item is tried at random poses (against
a wall, in a corner, or in the open, as the catalogue says) and kept at the first pose that

- lies on the room's floor, clear of the doorways (a strip as wide as the doorway plus 0.2 m and 1 m deep
  on both sides),
- keeps `ITEM_GAP_M` from every other solid item (a rug may lie under a table), and
- leaves the room passable: on a 0.1 m raster of the room, the cells the robot's centre may take (farther
  than its radius + `PASSAGE_MARGIN_M` from walls and solid items) still form one region holding every
  doorway's mouth. A pocket of a few cells (raster noise in a corner) is ignored.

A required slot (a bedroom's bed) gets more tries; an item that finds no pose is left out. Footprints stay
axis-aligned (a yawed catalogue item is stored with its size swapped).
"""

from __future__ import annotations

import random
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from llmnav.buildings.catalogue import ITEMS_BY_KEY, Item
from llmnav.buildings.kinds import ROOM_TYPES
from llmnav.buildings.layout import Door, FloorPlan, Rect, Room, snap

ITEM_GAP_M = 0.05  # [m] between two solid items
WALL_GAP_M = 0.02  # [m] between an item and the wall behind it
OPEN_WALL_GAP_M = 0.3  # [m] an item in the open keeps this much from the walls
DOOR_DEPTH_M = 1.0  # [m] depth of the kept-clear strip on each side of a doorway
PASSAGE_MARGIN_M = 0.25  # [m] beyond the robot radius: the grid margin (0.1), and room for a replan at 0.2
RASTER_M = 0.1  # [m] cell side of the passability raster
POCKET_CELLS = 6  # regions of at most this many cells are raster noise, not rooms cut in two
TRIES = 25
REQUIRED_TRIES = 80


@dataclass(frozen=True)
class Placed:
    """A placed item: the room it is in and its axis-aligned footprint."""

    item: Item
    room: int
    box: Rect  # [m] footprint (a cylinder's bounding square)

    @property
    def center(self) -> tuple[float, float]:
        """Centre [m]."""
        return (snap((self.box.x0 + self.box.x1) / 2, 0.025), snap((self.box.y0 + self.box.y1) / 2, 0.025))

    @property
    def size(self) -> tuple[float, float]:
        """Footprint (x, y) [m]."""
        return (snap(self.box.width, 0.025), snap(self.box.depth, 0.025))


def _door_zones(room: Room, doors: tuple[Door, ...]) -> list[Rect]:
    """Strips kept clear in front of the room's doorways (on the room's side)."""
    zones = []
    for door in doors:
        if room.index not in door.rooms:
            continue
        x, y = door.center
        half = door.width_m / 2 + 0.1
        if door.axis == "x":  # a wall along x: the strip reaches up or down into the room
            zones.append(Rect(x - half, y - DOOR_DEPTH_M, x + half, y + DOOR_DEPTH_M))
        else:
            zones.append(Rect(x - DOOR_DEPTH_M, y - half, x + DOOR_DEPTH_M, y + half))
    return zones


def _door_mouths(room: Room, doors: tuple[Door, ...], reach_m: float) -> list[tuple[float, float]]:
    """A point just inside the room in front of each of its doorways."""
    mouths = []
    cx, cy = room.rect.centre
    for door in doors:
        if room.index not in door.rooms:
            continue
        x, y = door.center
        if door.axis == "x":
            mouths.append((x, y + reach_m if cy > y else y - reach_m))
        else:
            mouths.append((x + reach_m if cx > x else x - reach_m, y))
    return mouths


def _passable(room: Room, solids: list[Rect], mouths: list[tuple[float, float]], clear_m: float) -> bool:
    """Whether the robot's free cells in the room form one region that holds every doorway mouth."""
    inside = room.inside
    cols = max(1, round(inside.width / RASTER_M))
    rows = max(1, round(inside.depth / RASTER_M))
    xs = inside.x0 + (np.arange(cols) + 0.5) * inside.width / cols
    ys = inside.y0 + (np.arange(rows) + 0.5) * inside.depth / rows
    gx, gy = np.meshgrid(xs, ys)
    wall = np.minimum(np.minimum(gx - inside.x0, inside.x1 - gx), np.minimum(gy - inside.y0, inside.y1 - gy))
    free = wall >= clear_m
    for box in solids:
        dx = np.maximum(np.maximum(box.x0 - gx, gx - box.x1), 0.0)
        dy = np.maximum(np.maximum(box.y0 - gy, gy - box.y1), 0.0)
        free &= np.hypot(dx, dy) >= clear_m
    labels, count = ndimage.label(free, structure=np.ones((3, 3), dtype=int))
    sizes = np.bincount(labels.ravel())[1:]
    if int((sizes > POCKET_CELLS).sum()) != 1:
        return False
    main = int(np.argmax(sizes)) + 1
    for x, y in mouths:
        col = min(cols - 1, max(0, int((x - inside.x0) / inside.width * cols)))
        row = min(rows - 1, max(0, int((y - inside.y0) / inside.depth * rows)))
        if labels[row, col] != main:
            return False
    return True


def _candidate(item: Item, inside: Rect, rng: random.Random) -> Rect | None:
    """A random footprint for `item` in the room, following its placement."""
    if item.placement == "centre":
        w, d = (item.width_m, item.depth_m) if item.cylinder or rng.random() < 0.5 else (item.depth_m, item.width_m)
        area = inside.shrunk(OPEN_WALL_GAP_M)
        if area.width < w or area.depth < d:
            return None
        x0 = snap(rng.uniform(area.x0, area.x1 - w))
        y0 = snap(rng.uniform(area.y0, area.y1 - d))
        return Rect(x0, y0, x0 + w, y0 + d)
    side = rng.choice(("south", "north", "west", "east"))
    along_len = inside.width if side in ("south", "north") else inside.depth
    w, d = item.width_m, item.depth_m
    span = along_len - 2 * WALL_GAP_M - w
    if span < 0:
        return None
    if item.placement == "corner":
        offset = WALL_GAP_M if rng.random() < 0.5 else WALL_GAP_M + span
    else:
        offset = WALL_GAP_M + snap(rng.uniform(0.0, span))
    if side == "south":
        return Rect(inside.x0 + offset, inside.y0 + WALL_GAP_M, inside.x0 + offset + w, inside.y0 + WALL_GAP_M + d)
    if side == "north":
        return Rect(inside.x0 + offset, inside.y1 - WALL_GAP_M - d, inside.x0 + offset + w, inside.y1 - WALL_GAP_M)
    if side == "west":
        return Rect(inside.x0 + WALL_GAP_M, inside.y0 + offset, inside.x0 + WALL_GAP_M + d, inside.y0 + offset + w)
    return Rect(inside.x1 - WALL_GAP_M - d, inside.y0 + offset, inside.x1 - WALL_GAP_M, inside.y0 + offset + w)


def _fits(box: Rect, item: Item, inside: Rect, zones: list[Rect], placed: list[Placed]) -> bool:
    if box.x0 < inside.x0 - 1e-9 or box.y0 < inside.y0 - 1e-9 or box.x1 > inside.x1 + 1e-9 or box.y1 > inside.y1 + 1e-9:
        return False
    if any(_overlap(box, zone) for zone in zones):
        return False
    for other in placed:
        if item.solid and other.item.solid:
            if box.gap_to(other.box) < ITEM_GAP_M:
                return False
        elif not item.solid and not other.item.solid and _overlap(box, other.box):
            return False
    return True


def _overlap(a: Rect, b: Rect) -> bool:
    """Whether two rectangles share area (touching edges do not count)."""
    return a.x0 < b.x1 and b.x0 < a.x1 and a.y0 < b.y1 and b.y0 < a.y1


def furnish(plan: FloorPlan, robot_radius_m: float, rng: random.Random) -> list[Placed]:
    """Every room's furniture, in room order and, within a room, in the order of its type's slots."""
    clear = robot_radius_m + PASSAGE_MARGIN_M
    placed: list[Placed] = []
    for room in plan.rooms:
        inside = room.inside
        zones = _door_zones(room, plan.doors)
        mouths = _door_mouths(room, plan.doors, clear + 0.05)
        in_room: list[Placed] = []
        slots = sorted(ROOM_TYPES[room.type_key].furniture, key=lambda s: not s.required)
        for slot in slots:
            item = ITEMS_BY_KEY[slot.item]
            for _ in range(rng.randint(slot.low, slot.high)):
                for _ in range(REQUIRED_TRIES if slot.required else TRIES):
                    box = _candidate(item, inside, rng)
                    if box is None or not _fits(box, item, inside, zones, in_room):
                        continue
                    solids = [p.box for p in in_room if p.item.solid and p.item.z_m < 1.0]
                    if item.solid and not _passable(room, [*solids, box], mouths, clear):
                        continue
                    in_room.append(Placed(item, room.index, box))
                    break
        placed.extend(in_room)
    return placed
