"""The kinds of building the generator makes: their size, room counts, room types and what each room holds.

Room types follow ProcTHOR's idea (Deitke et al., 2022): a building is asked for as a list of room types,
the layout gives each room a rectangle, and each type names the furniture it is furnished with. A room type
is also a labelled object of the scenario (its floor), so "go to the kitchen" has a target.

Layout styles:
- `bsp`: the interior is split by binary space partition into the rooms (a flat);
- `corridor`: a corridor runs along the long side and the rooms on both sides of it open onto it (an office);
- `hall`: one large hall, and the other rooms in a strip along one side of it (a warehouse).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from llmnav.buildings.catalogue import RGBA

LayoutStyle = Literal["bsp", "corridor", "hall"]


@dataclass(frozen=True)
class Slot:
    """Furniture of one item in a room type: how many, and whether the room needs one."""

    item: str  # catalogue key
    low: int
    high: int
    required: bool = False  # tried harder: a bedroom without a bed is not a bedroom


@dataclass(frozen=True)
class RoomType:
    """A type of room: its label and synonyms, floor colour, size rank and furniture."""

    key: str
    label: str
    aliases: tuple[str, ...]
    floor: RGBA
    size_rank: int  # larger types get larger rooms (ranks compared within one building)
    furniture: tuple[Slot, ...]


@dataclass(frozen=True)
class KindSpec:
    """A kind of building: default size and rooms, the limits a request must keep, its room types."""

    name: str
    layout: LayoutStyle
    robot: Literal["pr2", "burger"]
    size_m: tuple[float, float]  # [m] default outer size (x, y)
    rooms: int  # default number of rooms (the corridor or the hall included)
    max_rooms: int
    min_room_m: float  # [m] shortest side a room may have
    door_m: float  # [m] doorway width (widened to the robot's width + 0.3 m when narrower)
    corridor_m: float  # [m] corridor width (corridor layout) or side-strip depth (hall layout)
    first: tuple[str, ...]  # room types in the order they are added; the last repeats
    extra: tuple[str, ...]  # further room types, cycled, once `first` is used up


ROOM_TYPES: dict[str, RoomType] = {
    room.key: room
    for room in (
        RoomType(
            "living",
            "living room",
            ("lounge", "sitting room"),
            (0.62, 0.5, 0.38, 1.0),
            5,
            (
                Slot("sofa", 1, 1, required=True),
                Slot("armchair", 0, 2),
                Slot("coffee-table", 1, 1),
                Slot("tv-stand", 0, 1),
                Slot("bookshelf", 0, 2),
                Slot("plant", 0, 2),
                Slot("footstool", 0, 1),
                Slot("rug", 0, 1),
            ),
        ),
        RoomType(
            "kitchen",
            "kitchen",
            ("cookhouse",),
            (0.8, 0.8, 0.76, 1.0),
            3,
            (
                Slot("fridge", 1, 1, required=True),
                Slot("stove", 1, 1, required=True),
                Slot("sink", 1, 1),
                Slot("counter", 0, 1),
                Slot("dining-table", 0, 1),
                Slot("bin", 0, 1),
            ),
        ),
        RoomType(
            "dining",
            "dining room",
            ("dining area",),
            (0.6, 0.45, 0.32, 1.0),
            3,
            (Slot("dining-table", 1, 1, required=True), Slot("chair", 1, 3), Slot("plant", 0, 1)),
        ),
        RoomType(
            "bathroom",
            "bathroom",
            ("washroom",),
            (0.75, 0.82, 0.85, 1.0),
            1,
            (Slot("toilet", 1, 1, required=True), Slot("washbasin", 1, 1), Slot("bathtub", 0, 1)),
        ),
        RoomType(
            "bedroom",
            "bedroom",
            ("sleeping room",),
            (0.7, 0.62, 0.55, 1.0),
            4,
            (
                Slot("bed", 1, 1, required=True),
                Slot("wardrobe", 0, 1),
                Slot("nightstand", 0, 2),
                Slot("chair", 0, 1),
                Slot("rug", 0, 1),
            ),
        ),
        RoomType(
            "study",
            "study",
            ("home office",),
            (0.58, 0.55, 0.5, 1.0),
            2,
            (Slot("desk", 1, 1, required=True), Slot("chair", 0, 1), Slot("bookshelf", 0, 2), Slot("bin", 0, 1)),
        ),
        RoomType(
            "laundry",
            "laundry room",
            ("utility room",),
            (0.72, 0.74, 0.78, 1.0),
            0,
            (Slot("washing-machine", 1, 1, required=True), Slot("bin", 0, 1)),
        ),
        RoomType(
            "hallway",
            "hallway",
            ("entrance hall", "hall"),
            (0.52, 0.48, 0.44, 1.0),
            2,
            (Slot("coat-stand", 0, 1), Slot("shoe-rack", 0, 1), Slot("plant", 0, 1)),
        ),
        # --- office --------------------------------------------------------------------------------------
        RoomType(
            "corridor",
            "corridor",
            ("hallway", "passage"),
            (0.6, 0.6, 0.58, 1.0),
            9,
            (Slot("water-cooler", 0, 1), Slot("plant", 0, 2), Slot("bin", 0, 1)),
        ),
        RoomType(
            "office",
            "office",
            ("workroom",),
            (0.55, 0.57, 0.62, 1.0),
            3,
            (
                Slot("desk", 1, 2, required=True),
                Slot("office-chair", 1, 1),
                Slot("filing-cabinet", 0, 2),
                Slot("bookshelf", 0, 1),
                Slot("plant", 0, 1),
                Slot("bin", 0, 1),
            ),
        ),
        RoomType(
            "meeting",
            "meeting room",
            ("conference room", "boardroom"),
            (0.5, 0.52, 0.6, 1.0),
            5,
            (Slot("meeting-table", 1, 1, required=True), Slot("whiteboard", 0, 1), Slot("plant", 0, 1)),
        ),
        RoomType(
            "reception",
            "reception",
            ("lobby", "front office"),
            (0.66, 0.6, 0.5, 1.0),
            6,
            (
                Slot("reception-desk", 1, 1, required=True),
                Slot("sofa", 0, 1),
                Slot("plant", 0, 2),
                Slot("armchair", 0, 1),
            ),
        ),
        RoomType(
            "kitchenette",
            "kitchenette",
            ("tea kitchen", "break room"),
            (0.78, 0.78, 0.74, 1.0),
            2,
            (
                Slot("fridge", 1, 1, required=True),
                Slot("sink", 0, 1),
                Slot("vending-machine", 0, 1),
                Slot("dining-table", 0, 1),
                Slot("bin", 0, 1),
            ),
        ),
        RoomType(
            "restroom",
            "restroom",
            ("toilets", "washroom"),
            (0.75, 0.82, 0.85, 1.0),
            1,
            (Slot("toilet", 1, 2, required=True), Slot("washbasin", 1, 1)),
        ),
        RoomType(
            "copy",
            "copy room",
            ("print room",),
            (0.6, 0.6, 0.62, 1.0),
            1,
            (Slot("printer", 1, 1, required=True), Slot("filing-cabinet", 0, 2), Slot("bin", 0, 1)),
        ),
        RoomType(
            "server",
            "server room",
            ("data room",),
            (0.45, 0.47, 0.5, 1.0),
            0,
            (Slot("server-rack", 1, 3, required=True),),
        ),
        # --- warehouse -----------------------------------------------------------------------------------
        RoomType(
            "hall",
            "storage hall",
            ("warehouse floor", "storage area"),
            (0.5, 0.5, 0.48, 1.0),
            9,
            (
                Slot("rack", 2, 6, required=True),
                Slot("pallet", 1, 4),
                Slot("crate", 0, 3),
                Slot("carton", 0, 3),
                Slot("forklift", 0, 1),
                Slot("pallet-jack", 0, 1),
                Slot("barrel", 0, 3),
            ),
        ),
        RoomType(
            "workshop",
            "workshop",
            ("tool room", "repair shop"),
            (0.48, 0.46, 0.44, 1.0),
            3,
            (Slot("workbench", 1, 1, required=True), Slot("tool-cabinet", 0, 1), Slot("barrel", 0, 1)),
        ),
        RoomType(
            "site-office",
            "site office",
            ("warehouse office",),
            (0.55, 0.57, 0.62, 1.0),
            2,
            (Slot("desk", 1, 1, required=True), Slot("office-chair", 0, 1), Slot("filing-cabinet", 0, 1)),
        ),
        RoomType(
            "staff-room",
            "staff room",
            ("break room", "canteen"),
            (0.7, 0.7, 0.66, 1.0),
            2,
            (
                Slot("dining-table", 1, 1, required=True),
                Slot("locker", 0, 2),
                Slot("vending-machine", 0, 1),
                Slot("fridge", 0, 1),
            ),
        ),
    )
}

KINDS: dict[str, KindSpec] = {
    kind.name: kind
    for kind in (
        KindSpec(
            "flat",
            "bsp",
            "pr2",
            (12.0, 9.0),
            5,
            8,
            2.6,
            1.2,
            0.0,
            ("living", "kitchen", "bathroom", "bedroom"),
            ("bedroom", "study", "dining", "hallway", "laundry"),
        ),
        KindSpec(
            "office",
            "corridor",
            "pr2",
            (20.0, 12.0),
            7,
            14,
            3.0,
            1.3,
            2.2,
            ("corridor", "reception", "office", "meeting", "restroom"),
            ("office", "kitchenette", "copy", "office", "server"),
        ),
        KindSpec(
            "warehouse",
            "hall",
            "pr2",
            (24.0, 18.0),
            4,
            7,
            3.5,
            1.6,
            5.0,
            ("hall", "site-office", "restroom", "workshop"),
            ("staff-room", "site-office"),
        ),
    )
}


def room_types_for(kind: KindSpec, rooms: int) -> list[str]:
    """The room types of a building of `rooms` rooms: the kind's first ones, then its extras in turn."""
    chosen = list(kind.first[:rooms])
    while len(chosen) < rooms:
        chosen.append(kind.extra[(len(chosen) - len(kind.first)) % len(kind.extra)])
    return chosen
