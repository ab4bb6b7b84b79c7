"""The catalogue of furniture and fittings a generated building is furnished from.

Each item is a labelled object: a label, generic synonyms of it (`aliases`: a sofa is also a couch; never a
task's wording), a footprint and height, a colour, where in a room it stands, and what it is for (`uses`,
the keys of `USES`). Sizes are typical catalogue dimensions of the real thing. Low items (a coffee table, a
pallet, a footstool: 0.1-0.45 m) stay below a PR2's LiDAR (0.28 m) or a seated person's eye and are kept on
purpose: a robot must not run them over.

`USES` holds the wordings of tasks that name an object by what it is for ("somewhere to sit down"); the
targets of such a task are every object in the building whose item lists that use, found by this lookup,
so no wording is tied to one building's answer.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

RGBA = tuple[float, float, float, float]
Placement = Literal["wall", "centre", "corner"]


@dataclass(frozen=True)
class Item:
    """One kind of object: its names, size and where it goes."""

    key: str  # id stem in files: "sofa" -> sofa-1, sofa-2
    label: str
    aliases: tuple[str, ...]
    width_m: float  # [m] along the wall it stands against (or along x in the open)
    depth_m: float  # [m] away from that wall
    height_m: float  # [m]
    color: RGBA
    placement: Placement = "wall"
    cylinder: bool = False  # a round footprint of diameter width_m
    solid: bool = True  # False: a rug, a board on the wall: seen by the camera, passed through by the robot
    z_m: float = 0.0  # [m] bottom above the floor (a board on a wall)
    uses: tuple[str, ...] = ()


_WOOD: RGBA = (0.55, 0.38, 0.22, 1.0)
_DARK_WOOD: RGBA = (0.36, 0.24, 0.14, 1.0)
_WHITE: RGBA = (0.92, 0.92, 0.9, 1.0)
_STEEL: RGBA = (0.62, 0.64, 0.68, 1.0)
_GREY: RGBA = (0.42, 0.43, 0.46, 1.0)

ITEMS: tuple[Item, ...] = (
    # --- living, dining ---------------------------------------------------------------------------------
    Item("sofa", "sofa", ("couch", "settee"), 2.0, 0.9, 0.85, (0.25, 0.35, 0.55, 1.0), uses=("sit", "lie")),
    Item(
        "armchair",
        "armchair",
        ("easy chair", "lounge chair"),
        0.85,
        0.85,
        0.9,
        (0.6, 0.3, 0.25, 1.0),
        "corner",
        uses=("sit",),
    ),
    Item("coffee-table", "coffee table", ("low table", "cocktail table"), 1.1, 0.6, 0.4, _DARK_WOOD, "centre"),
    Item("footstool", "footstool", ("ottoman", "pouf"), 0.5, 0.5, 0.4, (0.7, 0.55, 0.3, 1.0), "centre", uses=("sit",)),
    Item("tv-stand", "tv stand", ("tv cabinet", "media console"), 1.5, 0.45, 0.5, (0.15, 0.15, 0.17, 1.0)),
    Item("bookshelf", "bookshelf", ("bookcase", "shelves"), 0.9, 0.35, 1.9, _WOOD, uses=("books",)),
    Item("dining-table", "dining table", ("table", "kitchen table"), 1.4, 0.9, 0.75, _WOOD, "centre", uses=("eat",)),
    Item(
        "plant",
        "potted plant",
        ("plant", "houseplant"),
        0.45,
        0.45,
        1.1,
        (0.2, 0.5, 0.22, 1.0),
        "corner",
        cylinder=True,
    ),
    Item("rug", "rug", ("carpet", "mat"), 1.6, 1.2, 0.01, (0.65, 0.2, 0.2, 1.0), "centre", solid=False),
    Item(
        "coat-stand",
        "coat stand",
        ("coat rack", "hat stand"),
        0.45,
        0.45,
        1.8,
        _DARK_WOOD,
        "corner",
        cylinder=True,
        uses=("coat",),
    ),
    Item("shoe-rack", "shoe rack", ("shoe shelf", "shoe cabinet"), 0.8, 0.3, 0.45, _WOOD),
    # --- kitchen, bathroom, laundry ----------------------------------------------------------------------
    Item("fridge", "fridge", ("refrigerator", "icebox"), 0.7, 0.7, 1.8, _WHITE, uses=("cold",)),
    Item("counter", "kitchen counter", ("counter", "worktop"), 1.8, 0.6, 0.9, (0.8, 0.78, 0.72, 1.0)),
    Item("stove", "stove", ("cooker", "range", "hob"), 0.6, 0.6, 0.9, (0.2, 0.2, 0.22, 1.0), uses=("cook",)),
    Item("sink", "kitchen sink", ("sink",), 0.8, 0.6, 0.9, _STEEL, uses=("wash",)),
    Item("toilet", "toilet", ("wc", "lavatory"), 0.4, 0.65, 0.8, _WHITE),
    Item("bathtub", "bathtub", ("bath", "tub"), 1.7, 0.75, 0.6, _WHITE, uses=("bathe",)),
    Item("washbasin", "washbasin", ("basin", "bathroom sink"), 0.55, 0.45, 0.85, _WHITE, uses=("wash",)),
    Item("washing-machine", "washing machine", ("washer",), 0.6, 0.6, 0.85, _WHITE, uses=("laundry",)),
    Item(
        "bin",
        "waste bin",
        ("rubbish bin", "trash can", "garbage can"),
        0.35,
        0.35,
        0.65,
        _GREY,
        "corner",
        cylinder=True,
        uses=("rubbish",),
    ),
    # --- bedroom, study --------------------------------------------------------------------------------
    Item("bed", "bed", ("double bed",), 1.6, 2.0, 0.5, (0.85, 0.85, 0.95, 1.0), uses=("lie", "sleep")),
    Item("wardrobe", "wardrobe", ("closet", "armoire"), 1.2, 0.6, 2.0, _WOOD, uses=("coat",)),
    Item("nightstand", "nightstand", ("bedside table",), 0.45, 0.4, 0.55, _WOOD),
    Item("desk", "desk", ("writing desk", "work desk"), 1.2, 0.6, 0.75, _WOOD, uses=("work",)),
    Item("chair", "chair", ("seat",), 0.5, 0.5, 0.9, _DARK_WOOD, "corner", uses=("sit",)),
    # --- office ----------------------------------------------------------------------------------------
    Item(
        "office-chair",
        "office chair",
        ("desk chair", "swivel chair"),
        0.65,
        0.65,
        1.05,
        (0.1, 0.1, 0.12, 1.0),
        "centre",
        cylinder=True,
        uses=("sit",),
    ),
    Item(
        "filing-cabinet", "filing cabinet", ("file cabinet", "drawer cabinet"), 0.5, 0.62, 1.3, _STEEL, uses=("files",)
    ),
    Item(
        "meeting-table",
        "meeting table",
        ("conference table", "boardroom table"),
        2.4,
        1.1,
        0.75,
        _WOOD,
        "centre",
        uses=("work", "eat"),
    ),
    Item("whiteboard", "whiteboard", ("dry-erase board", "marker board"), 1.5, 0.04, 1.0, _WHITE, solid=False, z_m=0.9),
    Item("printer", "printer", ("copier", "photocopier"), 0.6, 0.6, 1.1, (0.85, 0.85, 0.82, 1.0), uses=("print",)),
    Item(
        "water-cooler",
        "water cooler",
        ("water dispenser",),
        0.35,
        0.35,
        1.2,
        (0.55, 0.75, 0.95, 1.0),
        "corner",
        cylinder=True,
        uses=("water",),
    ),
    Item(
        "vending-machine", "vending machine", ("snack machine",), 0.9, 0.8, 1.8, (0.7, 0.1, 0.12, 1.0), uses=("snack",)
    ),
    Item("reception-desk", "reception desk", ("front desk",), 2.0, 0.7, 1.1, (0.75, 0.7, 0.6, 1.0)),
    Item("server-rack", "server rack", ("server cabinet", "rack cabinet"), 0.6, 1.0, 2.0, (0.12, 0.12, 0.14, 1.0)),
    Item("locker", "locker", ("cupboard", "steel cabinet"), 0.9, 0.5, 1.9, (0.3, 0.45, 0.6, 1.0), uses=("coat",)),
    # --- warehouse -------------------------------------------------------------------------------------
    Item("rack", "pallet rack", ("racking", "storage rack", "shelving"), 2.7, 1.1, 2.5, (0.2, 0.35, 0.7, 1.0)),
    Item("pallet", "pallet", ("wooden pallet", "skid"), 1.2, 0.8, 0.15, (0.8, 0.66, 0.45, 1.0), "centre"),
    Item("crate", "crate", ("wooden crate",), 0.8, 0.6, 0.6, (0.7, 0.52, 0.3, 1.0), "centre"),
    Item("carton", "cardboard box", ("carton", "box"), 0.5, 0.5, 0.5, (0.74, 0.58, 0.37, 1.0), "centre"),
    Item("forklift", "forklift", ("fork truck", "lift truck"), 1.2, 2.2, 2.1, (0.95, 0.7, 0.05, 1.0), "centre"),
    Item("pallet-jack", "pallet jack", ("pallet truck", "hand truck"), 0.55, 1.5, 1.2, (0.85, 0.2, 0.1, 1.0), "centre"),
    Item("barrel", "oil barrel", ("barrel", "drum"), 0.6, 0.6, 0.9, (0.12, 0.32, 0.52, 1.0), "corner", cylinder=True),
    Item("workbench", "workbench", ("work table", "tool bench"), 2.0, 0.8, 0.9, _GREY, uses=("repair",)),
    Item(
        "tool-cabinet",
        "tool cabinet",
        ("tool chest", "toolbox"),
        1.0,
        0.5,
        1.4,
        (0.75, 0.1, 0.1, 1.0),
        uses=("repair",),
    ),
)

ITEMS_BY_KEY: dict[str, Item] = {item.key: item for item in ITEMS}

# What an object is for -> wordings of a task that asks for it (text first, then paraphrases).
USES: dict[str, tuple[str, ...]] = {
    "sit": ("Find somewhere to sit down", "I need a place to sit", "Where could I take a seat?"),
    "lie": (
        "Find somewhere I can lie down",
        "I want to stretch out somewhere, find a spot",
        "Go to a place where I could lie flat",
    ),
    "sleep": ("Find somewhere to sleep", "Where can I get some sleep?", "Go to where I could take a nap"),
    "cold": ("Find somewhere to keep food cold", "Where can I chill a drink?", "Go to whatever keeps groceries fresh"),
    "cook": ("Find something to cook on", "Where could I heat up a pan?", "Go to where meals get cooked"),
    "wash": (
        "Find somewhere to wash my hands",
        "Where is there running water to rinse something?",
        "Go to a place with a tap",
    ),
    "bathe": ("Find somewhere to have a bath", "Where could I soak in hot water?", "Go to where one bathes"),
    "laundry": (
        "Find something to wash clothes in",
        "Where do the dirty clothes get cleaned?",
        "Go to the thing that does the laundry",
    ),
    "rubbish": (
        "Find somewhere to throw away rubbish",
        "Where can I get rid of this wrapper?",
        "Go to where waste goes",
    ),
    "books": ("Find somewhere to put a book away", "Where are books kept?", "Go to where reading matter is stored"),
    "eat": (
        "Find somewhere to eat a meal",
        "Where could I put my plate down and eat?",
        "Go to a place for having dinner",
    ),
    "coat": ("Find somewhere to hang a coat", "Where could I put my jacket away?", "Go to where coats are kept"),
    "work": (
        "Find somewhere I can work on a laptop",
        "Where could I set up to do some writing?",
        "Go to a surface for working at",
    ),
    "files": (
        "Find where paper records are kept",
        "Where would the files be stored?",
        "Go to the storage for documents",
    ),
    "print": (
        "Find something that can print a document",
        "Where can I get a paper copy made?",
        "Go to the machine that prints",
    ),
    "water": (
        "Find somewhere to get a drink of water",
        "I am thirsty, where is drinking water?",
        "Go to where I can fill a cup with water",
    ),
    "snack": ("Find somewhere to buy a snack", "Where can I get a chocolate bar?", "Go to where snacks are sold"),
    "repair": (
        "Find somewhere to fix a broken part",
        "Where would the tools for a repair be?",
        "Go to the place for mending things",
    ),
}
