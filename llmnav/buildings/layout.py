"""Floor plans: room rectangles, the doorways between them and the wall pieces that are left.

The first two steps of ProcTHOR's recipe (Deitke et al., 2022): the layout, then the doors. Rooms are
axis-aligned rectangles that tile the building's interior:

- `bsp`: binary space partition (the largest splittable rectangles are cut, across their longer side, at a
  random point that leaves both parts at least the minimum room side), retried until every room can be
  reached through doorways;
- `corridor`: a corridor along the long side, the other rooms cut side by side on both sides of it;
- `hall`: one hall, the other rooms side by side in a strip along its north side.

Doorways join a random spanning tree of the rooms that share enough wall, plus a few extra links (rooms
with two ways in). Walls are 0.2 m thick outside and 0.1 m inside; a wall line's pieces are what is left of
the rooms' shared edges once the doorways are cut out. Every coordinate is snapped to 0.05 m, so a file's
numbers stay short and exact.
"""

from __future__ import annotations

import random
from dataclasses import dataclass
from typing import Literal

from llmnav.errors import BadInputError

OUTER_WALL_M = 0.2  # [m] outer wall thickness, inside the bounds
INNER_WALL_M = 0.1  # [m] partition thickness, centred on the line between two rooms
JAMB_M = 0.3  # [m] wall kept between a doorway and a corner (or another wall's end)
SNAP_M = 0.05  # [m] coordinates are multiples of this
EXTRA_DOOR_P = 0.25  # [-] probability that two adjacent rooms not joined by the spanning tree get a door
LAYOUT_ATTEMPTS = 40  # BSP layouts tried before a request is called impossible

Axis = Literal["x", "y"]


def snap(value: float, step: float = SNAP_M) -> float:
    """`value` rounded to a multiple of `step` (and to 1e-6, so 0.1 * 3 prints as 0.3)."""
    return round(round(value / step) * step, 6)


@dataclass(frozen=True)
class Rect:
    """An axis-aligned rectangle [m]."""

    x0: float
    y0: float
    x1: float
    y1: float

    @property
    def width(self) -> float:
        """Extent along x [m]."""
        return self.x1 - self.x0

    @property
    def depth(self) -> float:
        """Extent along y [m]."""
        return self.y1 - self.y0

    @property
    def area(self) -> float:
        """Area [m²]."""
        return self.width * self.depth

    @property
    def centre(self) -> tuple[float, float]:
        """Centre [m]."""
        return ((self.x0 + self.x1) / 2, (self.y0 + self.y1) / 2)

    def shrunk(self, by_m: float) -> Rect:
        """The rectangle with every side moved inwards by `by_m` [m] (may come out empty)."""
        return Rect(self.x0 + by_m, self.y0 + by_m, self.x1 - by_m, self.y1 - by_m)

    def contains(self, x: float, y: float) -> bool:
        """Whether a point lies inside or on the edge."""
        return self.x0 <= x <= self.x1 and self.y0 <= y <= self.y1

    def gap_to(self, other: Rect) -> float:
        """Distance [m] between the two rectangles (0 when they touch or overlap)."""
        dx = max(other.x0 - self.x1, self.x0 - other.x1, 0.0)
        dy = max(other.y0 - self.y1, self.y0 - other.y1, 0.0)
        return float((dx * dx + dy * dy) ** 0.5)


@dataclass(frozen=True)
class Room:
    """A room: its index in the plan, its rectangle (between wall centre lines) and its type key."""

    index: int
    rect: Rect
    type_key: str

    @property
    def inside(self) -> Rect:
        """The floor between the wall faces [m]."""
        return self.rect.shrunk(INNER_WALL_M / 2)


@dataclass(frozen=True)
class Door:
    """A doorway between two rooms: a gap of `width_m` centred on `center` in a wall running along `axis`."""

    rooms: tuple[int, int]
    center: tuple[float, float]  # [m]
    axis: Axis  # the wall's direction: "x" = a wall along x (the doorway is crossed along y)
    width_m: float  # [m]


@dataclass(frozen=True)
class WallBox:
    """One box of wall [m]: centre and size."""

    center: tuple[float, float]
    size: tuple[float, float]


@dataclass(frozen=True)
class FloorPlan:
    """Rooms, doorways and walls of a building whose outer corners are (0, 0) and `size`."""

    size: tuple[float, float]  # [m]
    rooms: tuple[Room, ...]
    doors: tuple[Door, ...]
    walls: tuple[WallBox, ...]


@dataclass(frozen=True)
class _Contact:
    """Two rooms sharing a stretch of wall line: axis, the line's coordinate, and the shared interval."""

    a: int
    b: int
    axis: Axis
    line: float
    lo: float
    hi: float


def _contacts(rects: list[Rect], min_len: float) -> list[_Contact]:
    """Pairs of rectangles sharing at least `min_len` [m] of an edge, in index order."""
    out = []
    eps = 1e-6
    for i, a in enumerate(rects):
        for j in range(i + 1, len(rects)):
            b = rects[j]
            for line_a, line_b, axis in ((a.x1, b.x0, "y"), (a.x0, b.x1, "y"), (a.y1, b.y0, "x"), (a.y0, b.y1, "x")):
                if abs(line_a - line_b) > eps:
                    continue
                lo, hi = (max(a.y0, b.y0), min(a.y1, b.y1)) if axis == "y" else (max(a.x0, b.x0), min(a.x1, b.x1))
                if hi - lo >= min_len - eps:
                    out.append(_Contact(i, j, axis, line_a, lo, hi))  # type: ignore[arg-type]
    return out


def _split_lengths(total: float, count: int, min_len: float, rng: random.Random) -> list[float] | None:
    """`count` random lengths of at least `min_len` summing to `total`, cut points snapped to 0.1 m."""
    if count * min_len > total + 1e-9:
        return None
    weights = [0.5 + rng.random() for _ in range(count)]
    spare = total - count * min_len
    cuts, acc = [], 0.0
    for weight in weights[:-1]:
        acc += min_len + spare * weight / sum(weights)
        cuts.append(snap(acc, 0.1))
    edges = [0.0, *cuts, total]
    lengths = [edges[k + 1] - edges[k] for k in range(count)]
    if min(lengths) < min_len - 1e-6:  # snapping ate into a minimum: fall back to equal parts
        lengths = [total / count] * count
    return lengths


def _strip(rect: Rect, count: int, min_len: float, rng: random.Random) -> list[Rect] | None:
    """`rect` cut along x into `count` rooms of at least `min_len` [m] width."""
    lengths = _split_lengths(rect.width, count, min_len, rng)
    if lengths is None:
        return None
    out, x = [], rect.x0
    for k, length in enumerate(lengths):
        x1 = rect.x1 if k == count - 1 else snap(x + length)
        out.append(Rect(x, rect.y0, x1, rect.y1))
        x = x1
    return out


def _bsp(rect: Rect, count: int, min_len: float, rng: random.Random) -> list[Rect] | None:
    """Binary space partition of `rect` into `count` rectangles with sides of at least `min_len` [m]."""
    leaves = [rect]
    while len(leaves) < count:
        splittable = [r for r in leaves if max(r.width, r.depth) >= 2 * min_len]
        if not splittable:
            return None
        chosen = rng.choices(splittable, weights=[r.area for r in splittable])[0]
        can_x, can_y = chosen.width >= 2 * min_len, chosen.depth >= 2 * min_len
        # Cut across the longer side; a near-square room may be cut either way.
        if can_x and can_y and 0.8 < chosen.width / chosen.depth < 1.25:
            across_x = rng.random() < 0.5
        else:
            across_x = can_x and (chosen.width >= chosen.depth or not can_y)
        lo, hi = (chosen.x0, chosen.x1) if across_x else (chosen.y0, chosen.y1)
        cut = snap(rng.uniform(lo + min_len, hi - min_len), 0.1)
        cut = min(max(cut, snap(lo + min_len + 0.05, 0.1)), snap(hi - min_len - 0.05, 0.1))
        if cut - lo < min_len - 1e-6 or hi - cut < min_len - 1e-6:
            cut = snap((lo + hi) / 2)
        leaves.remove(chosen)
        if across_x:
            leaves += [Rect(chosen.x0, chosen.y0, cut, chosen.y1), Rect(cut, chosen.y0, chosen.x1, chosen.y1)]
        else:
            leaves += [Rect(chosen.x0, chosen.y0, chosen.x1, cut), Rect(chosen.x0, cut, chosen.x1, chosen.y1)]
    return sorted(leaves, key=lambda r: (r.y0, r.x0))


def _corridor(inner: Rect, count: int, min_len: float, corridor_m: float, rng: random.Random) -> list[Rect] | None:
    """A corridor along x and `count - 1` rooms on its two sides; the corridor comes first."""
    side_rooms = count - 1
    north, south = (side_rooms + 1) // 2, side_rooms // 2
    spare = inner.depth - corridor_m
    if side_rooms == 0:
        return [inner]
    if south == 0:  # one side only: the corridor runs along the south wall
        if spare < min_len:
            return None
        corridor = Rect(inner.x0, inner.y0, inner.x1, snap(inner.y0 + corridor_m))
        rooms = _strip(Rect(inner.x0, corridor.y1, inner.x1, inner.y1), north, min_len, rng)
        return None if rooms is None else [corridor, *rooms]
    if spare < 2 * min_len:
        return None
    y0 = snap(inner.y0 + min_len + rng.uniform(0, spare - 2 * min_len), 0.1)
    y0 = min(max(y0, inner.y0 + min_len), inner.y1 - min_len - corridor_m)
    corridor = Rect(inner.x0, y0, inner.x1, snap(y0 + corridor_m))
    south_rooms = _strip(Rect(inner.x0, inner.y0, inner.x1, corridor.y0), south, min_len, rng)
    north_rooms = _strip(Rect(inner.x0, corridor.y1, inner.x1, inner.y1), north, min_len, rng)
    if south_rooms is None or north_rooms is None:
        return None
    return [corridor, *south_rooms, *north_rooms]


def _hall(inner: Rect, count: int, min_len: float, strip_m: float, rng: random.Random) -> list[Rect] | None:
    """A hall and `count - 1` rooms in a strip along its north side; the hall comes first."""
    if count == 1:
        return [inner]
    y_cut = snap(inner.y1 - strip_m)
    if y_cut - inner.y0 < 2 * min_len:
        return None
    rooms = _strip(Rect(inner.x0, y_cut, inner.x1, inner.y1), count - 1, min_len, rng)
    return None if rooms is None else [Rect(inner.x0, inner.y0, inner.x1, y_cut), *rooms]


def _doors(
    rects: list[Rect], contacts: list[_Contact], door_m: float, hub: int | None, rng: random.Random
) -> list[Door] | None:
    """Doorways on a random spanning tree of `contacts` plus a few extras; None if the rooms stay apart.

    With a `hub` (the corridor, the hall) every room that touches it gets its door there first.
    """
    parent = list(range(len(rects)))

    def root(k: int) -> int:
        while parent[k] != k:
            parent[k] = parent[parent[k]]
            k = parent[k]
        return k

    order = list(contacts)
    rng.shuffle(order)
    if hub is not None:
        order.sort(key=lambda c: hub not in (c.a, c.b))  # stable: hub links first, each group shuffled
    doors = []
    for contact in order:
        joined = root(contact.a) != root(contact.b)
        if not joined and rng.random() >= EXTRA_DOOR_P:
            continue
        parent[root(contact.a)] = root(contact.b)
        lo, hi = contact.lo + JAMB_M + door_m / 2, contact.hi - JAMB_M - door_m / 2
        along = snap(rng.uniform(lo, hi)) if hi > lo else snap((contact.lo + contact.hi) / 2)
        along = min(max(along, lo), hi) if hi >= lo else along
        center = (contact.line, along) if contact.axis == "y" else (along, contact.line)
        doors.append(Door((contact.a, contact.b), center, contact.axis, door_m))
    if len({root(k) for k in range(len(rects))}) > 1:
        return None
    return doors


def _wall_pieces(rects: list[Rect], doors: list[Door], size: tuple[float, float]) -> list[WallBox]:
    """The outer walls and every partition line with its doorways cut out."""
    width, depth = size
    t = OUTER_WALL_M
    walls = [
        WallBox((snap(width / 2), t / 2), (width, t)),
        WallBox((snap(width / 2), snap(depth - t / 2)), (width, t)),
        WallBox((t / 2, snap(depth / 2)), (t, snap(depth - 2 * t))),
        WallBox((snap(width - t / 2), snap(depth / 2)), (t, snap(depth - 2 * t))),
    ]
    # Interior edges of the rooms, gathered per line: (axis, coordinate) -> intervals.
    lines: dict[tuple[str, float], list[tuple[float, float]]] = {}
    for r in rects:
        for axis, coord, lo, hi in (
            ("x", r.y0, r.x0, r.x1),
            ("x", r.y1, r.x0, r.x1),
            ("y", r.x0, r.y0, r.y1),
            ("y", r.x1, r.y0, r.y1),
        ):
            outer = coord <= t + 1e-6 or coord >= (depth if axis == "x" else width) - t - 1e-6
            if not outer:
                lines.setdefault((axis, round(coord, 6)), []).append((lo, hi))
    half = INNER_WALL_M / 2
    for (axis, coord), intervals in sorted(lines.items()):
        merged: list[list[float]] = []
        for lo, hi in sorted(intervals):
            if merged and lo <= merged[-1][1] + 1e-6:
                merged[-1][1] = max(merged[-1][1], hi)
            else:
                merged.append([lo, hi])
        gaps = sorted(
            (d.center[0] if axis == "x" else d.center[1], d.width_m)
            for d in doors
            if d.axis == axis and abs((d.center[1] if axis == "x" else d.center[0]) - coord) < 1e-6
        )
        for lo, hi in merged:
            # Pieces between doorways; ends that meet another wall reach half a thickness further (closed corners).
            pieces, start, start_is_door = [], lo, False
            for middle, door_width in gaps:
                if lo < middle < hi:
                    pieces.append((start, middle - door_width / 2, start_is_door, True))
                    start, start_is_door = middle + door_width / 2, True
            pieces.append((start, hi, start_is_door, False))
            for a, b, a_door, b_door in pieces:
                a, b = (a if a_door else a - half), (b if b_door else b + half)
                if b - a <= 1e-6:
                    continue
                centre_along, length = snap((a + b) / 2, 0.025), snap(b - a, 0.025)
                if axis == "x":
                    walls.append(WallBox((centre_along, coord), (length, INNER_WALL_M)))
                else:
                    walls.append(WallBox((coord, centre_along), (INNER_WALL_M, length)))
    return walls


def plan_floor(
    layout: str,
    size: tuple[float, float],
    room_types: list[str],
    *,
    min_room_m: float,
    door_m: float,
    corridor_m: float,
    size_ranks: dict[str, int],
    rng: random.Random,
) -> FloorPlan:
    """Rooms, doorways and walls of a building of outer `size` [m] holding rooms of the given types.

    Raises BadInputError when the rooms cannot fit (the building is too small for them).
    """
    count = len(room_types)
    width, depth = size
    t = OUTER_WALL_M
    inner = Rect(t, t, snap(width - t), snap(depth - t))
    if count * min_room_m * min_room_m > inner.area + 1e-9:
        raise BadInputError(
            f"a {width:g} m x {depth:g} m building cannot hold {count} rooms of at least "
            f"{min_room_m:g} m x {min_room_m:g} m"
        )
    need = door_m + 2 * JAMB_M  # [m] shared wall a doorway needs
    for _ in range(LAYOUT_ATTEMPTS):
        if layout == "bsp":
            rects = _bsp(inner, count, min_room_m, rng)
            hub = None
        elif layout == "corridor":
            rects = _corridor(inner, count, min_room_m, corridor_m, rng)
            hub = 0
        else:
            rects = _hall(inner, count, min_room_m, corridor_m, rng)
            hub = 0
        if rects is None:
            break
        doors = _doors(rects, _contacts(rects, need), door_m, hub, rng)
        if doors is None:
            continue
        # Larger rooms get the types that want more space (the hub keeps the first type).
        fixed = 1 if hub is not None else 0
        by_area = sorted(range(fixed, count), key=lambda k: (-rects[k].area, k))
        by_rank = sorted(room_types[fixed:], key=lambda key: -size_ranks[key])
        types = {k: key for k, key in zip(by_area, by_rank, strict=True)}
        if fixed:
            types[0] = room_types[0]
        rooms = tuple(Room(k, rects[k], types[k]) for k in range(count))
        return FloorPlan(size, rooms, tuple(doors), tuple(_wall_pieces(rects, doors, size)))
    raise BadInputError(
        f"a {width:g} m x {depth:g} m building cannot be cut into {count} rooms of at least {min_room_m:g} m "
        f"a side joined by {door_m:g} m doorways"
    )
