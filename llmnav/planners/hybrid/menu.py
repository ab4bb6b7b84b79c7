"""The hybrid planner's option menu: which choices a decision offers, in which order, in which words.

Each decision offers landmarks to go to (the nearest `max_landmarks` places; every known one for scored
decisions, which read no prompt), frontier clusters of the robot's own LiDAR map to explore (the nearest
`max_frontiers`; none when the map is published), one full turn to look around (not twice on one spot)
and Finish.

Each option is one short line (`3. Go to oil barrel, 8 m front-right, visited`): whole metres and one of
eight directions, because the navigation stack does the driving and every digit is a token.

The order (`--menu-order`): `distance` is neutral (places by distance, ties by kind then name, then the
full turn, then Finish; the place the robot stands at only names itself in the Finish line).
`relevance` is ordered for a weak model that favours the first and the last entry, using name matching
of the task against object names: while nothing the task names is known, looking around and exploring
come first; a named landmark comes first once known; at it, the menu shrinks to Finish (and one more
look); an unfinished task never lists Finish last.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

import numpy as np

from llmnav.core.geometry import Point, Pose2D
from llmnav.mapping.frontiers import frontier_clusters, goal_cells
from llmnav.mapping.grid import nearest_free_cell
from llmnav.planners.hybrid.memory import Memory, relevance_order

if TYPE_CHECKING:
    from llmnav.mapping.grid import GridGeometry, LidarMap, OccupancyGrid
    from llmnav.planners.base import EpisodeContext
    from llmnav.planners.hybrid.config import HybridConfig

OptionKind = Literal["landmark", "frontier", "scan", "complete"]

# [m] goals for a frontier lie within the grid's inflation plus this of one of its cells (sensed mode:
# unknown space is inflated, so the frontier cells themselves are never free)
FRONTIER_GOAL_BAND_M = 0.25

# The menu's direction words, counter-clockwise from ahead in 45 deg steps.
SECTORS = ("ahead", "front-left", "left", "back-left", "behind", "back-right", "right", "front-right")


@dataclass
class Option:
    """One numbered choice and how to carry it out."""

    number: int
    kind: OptionKind
    text: str
    goal: Point | None = None  # [m] where to drive
    face: Point | None = None  # [m] what to face on arrival
    landmark_id: str | None = None
    name: str = ""  # the landmark's name, for the result line
    at: tuple[str, ...] = ()  # Finish: the names of the landmarks the robot stands at
    distance_m: float = 0.0  # [m] from the robot to `goal`
    standing: bool = False  # landmark: the robot is there (at its stand point, or as close as is safe)
    utility: float = 0.0  # frontier: what exploring it is worth (`frontier_utility`)
    near: tuple[str, ...] = ()  # frontier: names of the known landmarks near it, nearest first (`landmarks_near`)
    # a relational place ("spot between the stairs and the oil barrel"): where it lies [m], from the
    # landmark estimates it is built from (`relational_options`)
    place: Point | None = None
    parts: tuple[str, ...] = ()  # relational place: the names of the landmarks it is built from

    @property
    def key(self) -> str:
        """What `Memory.unreachable` calls this option: its landmark id, or a relational place's words and spot."""
        if self.place is not None:
            return f"{self.name}@{self.place[0]:.1f},{self.place[1]:.1f}"
        return self.landmark_id or ""

    @property
    def goal_name(self) -> str:
        """What the option drives to, in a few words."""
        return self.name or ("the explored edge" if self.kind == "frontier" else "the goal")


@dataclass(frozen=True)
class MenuInputs:
    """What a menu is built from."""

    ctx: EpisodeContext
    cfg: HybridConfig
    grids: list[OccupancyGrid]  # planning grids, roomiest first
    lidar_map: LidarMap
    memory: Memory
    pose: Pose2D  # where the planner believes the robot is

    @property
    def sensed(self) -> bool:
        """Whether the planner knows only what it sensed."""
        return self.ctx.information == "sensed"


def build_menu(inputs: MenuInputs, *, scored: bool = False) -> list[Option]:
    """The numbered menu (`scored`: no cap on landmarks)."""
    places = landmark_options(inputs, scored=scored) + frontier_options(inputs, scored=scored)
    # relational places read no prompt only when scored (a generated menu stays short), and only for a
    # task that asks for a relation
    if scored and asks_for_relation(inputs.ctx.task.text):
        places += relational_options(inputs)
    memory, pose, cfg = inputs.memory, inputs.pose, inputs.cfg
    scanned_here = memory.scanned_at is not None and pose.distance_to(*memory.scanned_at) < cfg.rescan_m
    # A second full turn on the same spot shows nothing new (the world is static): not offered. The words
    # say what the robot does (a task may ask for the turn itself, in any wording).
    turn = [] if scanned_here else [Option(0, "scan", "Turn a full circle to look around")]
    if relevance_order(inputs.ctx):
        menu = relevance_menu(inputs, places, turn)
    else:
        menu = neutral_menu(pose, places, turn)
    for number, option in enumerate(menu, start=1):
        option.number = number
    return menu


# --- the entries ---------------------------------------------------------------------------------
def landmark_options(inputs: MenuInputs, *, scored: bool) -> list[Option]:
    """Known landmarks with a reachable stand point, wanted ones first, then by distance.

    The cap counts places to drive to: the landmark the robot stands at is listed besides them (as
    Finish's "at", or as "you are there"), and one without a reachable stand point is not listed.
    """
    memory, pose, cfg = inputs.memory, inputs.pose, inputs.cfg
    ranked = sorted(
        memory.landmarks.items(),
        key=lambda item: (item[0] not in memory.wanted, pose.distance_to(*item[1])),
    )
    options: list[Option] = []
    places = 0
    for object_id, position in ranked:
        if object_id in memory.unreachable:
            continue
        # Scored decisions read no prompt: every known landmark stays on the menu.
        if places >= cfg.max_landmarks and not scored:
            break
        option = landmark_option(inputs, object_id, position)
        if option is None:
            continue
        places += not option.standing
        options.append(option)
    return options


def landmark_option(inputs: MenuInputs, object_id: str, position: Point) -> Option | None:
    """Going to one landmark, or None when the robot has nowhere to stand near it."""
    memory, pose, cfg = inputs.memory, inputs.pose, inputs.cfg
    # Sensed: the detector measures to the object's goal point, so the estimate is that point.
    scenario = inputs.ctx.scenario
    true_goal = None if inputs.sensed else scenario.object(object_id).goal
    goal = approach(inputs, position if inputs.sensed else true_goal, position)
    if goal is None:
        return None
    # Where the motion layer refused to go closer, the spot it allowed counts as arrival.
    allowed = memory.closest.get(object_id)
    standing = pose.distance_to(*goal) <= cfg.arrived_m or (
        allowed is not None and pose.distance_to(*allowed) <= cfg.arrived_m
    )
    # Near its stand point the bearing to the point says nothing: say where the robot is instead.
    notes = ["you are there" if standing else where(pose, goal)]
    if object_id in memory.wanted:
        notes.append("name matches task")
    if object_id in memory.visited:
        notes.append("visited")
    name = memory.label(object_id)
    return Option(
        0,
        "landmark",
        f"Go to {name}, {', '.join(notes)}",
        goal=goal,
        face=position if inputs.sensed else scenario.object(object_id).center,
        landmark_id=object_id,
        name=name,
        distance_m=pose.distance_to(*goal),
        standing=standing,
    )


def frontier_options(inputs: MenuInputs, *, scored: bool = False) -> list[Option]:
    """The frontier clusters worth exploring, the first `max_frontiers` by `-o explore`; none with a published map.

    `nearest` ranks them by distance, `utility` and `scored` by `frontier_utility` (a scored decision reads
    no prompt: it gets up to `max_frontiers_scored` and weighs their descriptions itself). With a published
    map every landmark is listed already: exploring would only distract the model. A frontier the robot
    stands at, or one it has reached before, shows nothing new from there (its unknown side cannot be seen
    from the free cells): offering it again only wastes decisions. Nor is one that had no path on the map,
    until the next frontier is explored.
    """
    if inputs.ctx.scenario.corridors:
        return []
    pose, cfg, memory = inputs.pose, inputs.cfg, inputs.memory
    found = [
        (centre, length)
        for centre, length in frontier_points(inputs)
        if pose.distance_to(*centre) >= cfg.min_hop_m
        and all(math.dist(centre, seen) > cfg.rescan_m for seen in (*memory.explored, *memory.no_path))
    ]
    worth = [(frontier_utility(length, pose.distance_to(*c), cfg.frontier_decay_per_m), c) for c, length in found]
    explore = inputs.ctx.options.explore
    if explore != "nearest":  # (found is nearest first)
        worth.sort(key=lambda item: -item[0])  # stable: among equals the nearer
    count = cfg.max_frontiers_scored if scored and explore == "scored" else cfg.max_frontiers
    return [
        Option(
            0,
            "frontier",
            f"Explore, {where(pose, centre)}",
            goal=centre,
            distance_m=pose.distance_to(*centre),
            utility=utility,
            near=landmarks_near(memory, centre, cfg.describe_radius_m, cfg.describe_max),
        )
        for utility, centre in worth[:count]
    ]


# English words that place something relative to other things: the relations `relational_options` builds
# ("between": between, halfway, in the middle of; "beside": beside, next to, near, by, close to, alongside).
_RELATION = re.compile(r"\b(between|halfway|middle|beside|next to|near|nearby|by|close to|alongside|adjacent)\b", re.I)


def asks_for_relation(task: str) -> bool:
    """Whether `task` words a place relative to other things ("Go between the stairs and the oil barrels").

    Relational places are offered only then. Offered for every task, they cost the 135M model most of its
    failures on generated flats, whose tasks never ask for one: it scores the longer "spot beside the
    chair" above the names in it (5.3 against 3.1 nats for "Go to the coffee table"). On flats 0-2 (T1-T7,
    pose 1, `sensed`) it reached 14/21 with them on every menu and 20/21 and 21/21 (scored, nearest
    frontiers) without. The model itself cannot tell such a task apart: asked to score "stop between
    two things" and "stop beside something" against "drive to something", it called "Find somewhere I
    can lie down" relational and "Move to the spot between the two tables" not. The words are the
    relations in general, not any scenario's.
    """
    return _RELATION.search(task) is not None


def relational_options(inputs: MenuInputs) -> list[Option]:
    """Places named by the landmarks around them: "spot between the A and the B", "spot beside the A".

    A task may name a place that is no landmark ("Go between the stairs and the oil barrels"). Built from
    the landmarks already seen (the planner's own estimates): between two of different names at most
    `between_max_m` apart (their midpoint), beside each one (its estimate); the `max_relational` nearest
    to the robot, each with a reachable stand point. Scored like names (`scoring.ScoredChooser`).
    """
    memory, pose, cfg = inputs.memory, inputs.pose, inputs.cfg
    known = sorted((memory.label(oid), position) for oid, position in memory.landmarks.items())
    spots: list[tuple[str, Point, tuple[str, ...]]] = []
    for index, (first, a) in enumerate(known):
        spots.append((f"spot beside the {first}", a, (first,)))
        for second, b in known[index + 1 :]:
            if first != second and math.dist(a, b) <= cfg.between_max_m:
                middle = ((a[0] + b[0]) / 2, (a[1] + b[1]) / 2)
                spots.append((f"spot between the {first} and the {second}", middle, (first, second)))
    spots.sort(key=lambda spot: pose.distance_to(*spot[1]))
    options: list[Option] = []
    for name, spot, parts in spots:
        if len(options) >= cfg.max_relational:
            break
        option = Option(0, "landmark", f"Go to the {name}", name=name, place=spot, face=spot, parts=parts)
        if option.key in memory.unreachable:
            continue
        goal = nearest_stand(inputs, spot)
        if goal is None:
            continue
        option.goal, option.distance_m = goal, pose.distance_to(*goal)
        option.standing = option.distance_m <= cfg.arrived_m
        options.append(option)
    return options


def landmarks_near(memory: Memory, point: Point, radius_m: float, most: int) -> tuple[str, ...]:
    """Names of the known landmarks within `radius_m` [m] of `point`, nearest first, each name once, at most `most`.

    What the robot has seen near a frontier says what the unknown beyond it may hold (a wardrobe and a
    bed: a bedroom). Known positions only: the planner's own estimates, never the scenario's.
    """
    near = sorted(
        (math.dist(point, position), memory.label(object_id))
        for object_id, position in memory.landmarks.items()
        if math.dist(point, position) <= radius_m
    )
    return tuple(dict.fromkeys(name for _, name in near))[:most]


def frontier_utility(length_m: float, distance_m: float, decay_per_m: float) -> float:
    """What exploring a frontier is worth: length * exp(-decay * distance).

    Its length [m] says how much unknown it borders; the drive to it discounts that (the gain-over-cost
    form of next-best-view exploration, Gonzalez-Banos & Latombe 2002). A long frontier across the flat
    beats a speck next to the robot.
    """
    return length_m * math.exp(-decay_per_m * distance_m)


# --- the orders ----------------------------------------------------------------------------------
def neutral_menu(pose: Pose2D, places: list[Option], turn: list[Option]) -> list[Option]:
    """Every place by distance (ties: landmarks first, then by name), a look, then Finish.

    Going to where the robot already stands does nothing, so that entry becomes a fact in the Finish
    line instead (whatever the task is).
    """
    here = [o for o in places if o.kind == "landmark" and o.standing and o.place is None]
    moves = sorted(
        (o for o in places if o not in here),
        key=lambda o: (
            round(pose.distance_to(*o.goal), 1) if o.goal is not None else 0.0,
            o.kind != "landmark",
            o.text,
        ),
    )
    at = ", ".join(o.name for o in here)
    finish = Option(0, "complete", "Finish" + (f" (at {at})" if at else ""), at=tuple(o.name for o in here))
    return [*moves, *turn, finish]


def relevance_menu(inputs: MenuInputs, places: list[Option], turn: list[Option]) -> list[Option]:
    """Most relevant first: small models lean heavily toward option 1 (and the last one)."""
    memory = inputs.memory
    wanted = memory.wanted
    arrived = [o for o in places if o.landmark_id in wanted and o.landmark_id in memory.visited and o.standing]
    # A task that names nothing (turn around, look around) is served by the scan, then by finishing.
    turning_task = not wanted and inputs.ctx.task.kind in ("rotate", "explore")
    done = _finish_note(arrived, turning_task, memory)
    finish = Option(0, "complete", "Finish" + done, at=tuple(o.name for o in arrived))
    # While nothing the task names is known, looking around (once per spot) and exploring come before
    # unrelated landmarks.
    useful = [o for o in places if o.kind == "landmark" and o.landmark_id in wanted and o not in arrived]
    # Going to where the robot already stands does nothing: once there, that entry only distracts.
    others = [o for o in places if o.kind == "landmark" and o not in useful and o not in arrived]
    frontier = [o for o in places if o.kind == "frontier"]
    if done:
        # At what the task names (or after the asked-for turn) nothing else serves the task: a short menu
        # keeps a weak model from wandering off (measured: it did, at random, from a full one).
        return [finish, *turn]
    if turning_task:
        menu = [*turn, *others, *frontier, finish]
    elif useful:
        menu = [*useful, *others, *frontier, *turn, finish]
    else:
        menu = [*turn, *frontier, *others, finish]
    if len(menu) >= 3:
        # The tiny model also favours the last entry; finishing early is the one unrecoverable mistake,
        # so an unfinished task never lists Finish last.
        menu[-2], menu[-1] = menu[-1], menu[-2]
    return menu


def _finish_note(arrived: list[Option], turning_task: bool, memory: Memory) -> str:
    """What the Finish line says the robot has done ("" while the task is not done)."""
    if arrived:
        return f" (at {arrived[0].name})"
    if turning_task and memory.scans:
        return " (you have looked around)"
    return ""


# --- geometry of the entries ---------------------------------------------------------------------
PLAIN_GRIDS = 2  # the roomy and the plain planning grids come first in `MenuInputs.grids`


def approach(inputs: MenuInputs, goal: Point | None, position: Point) -> Point | None:
    """Where to stand: the goal point if the robot fits there, else the nearest free stand-off cell.

    The stand-off cell comes from the roomiest grid that has one.
    """
    # Stand points keep the plain clearance at least: the narrower grids are for passing through doorways.
    grids, cfg, pose = inputs.grids[:PLAIN_GRIDS], inputs.cfg, inputs.pose
    if goal is not None and grids[-1].is_free(*goal):
        return goal
    for grid in grids:
        # Only the window around the ring can hold a stand-off cell (the whole grid is ~30x larger);
        # row-major order within it is the grid's, so argmin breaks ties the same way.
        rows, cols = _window(grid.geometry, position, cfg.approach_max_m)
        xs, ys = grid.geometry.centres(rows, cols)
        ring = np.hypot(xs - position[0], ys - position[1])
        ok = (~grid.blocked[rows, cols]) & (ring >= cfg.approach_min_m) & (ring <= cfg.approach_max_m)
        if ok.any():
            cost = np.where(ok, np.hypot(xs - pose.x, ys - pose.y), np.inf)
            row, col = np.unravel_index(int(np.argmin(cost)), cost.shape)
            return grid.geometry.cell_to_world(rows.start + int(row), cols.start + int(col))
    return None


def nearest_stand(inputs: MenuInputs, spot: Point) -> Point | None:
    """The free cell nearest `spot` within `approach_max_m` (roomiest grid first).

    A relational place is a spot to stand on, not an object to keep a stand-off from.
    """
    for grid in inputs.grids[:PLAIN_GRIDS]:
        cell = nearest_free_cell(grid.blocked, grid.geometry, spot[0], spot[1], inputs.cfg.approach_max_m)
        if cell is not None:
            return grid.geometry.cell_to_world(*cell)
    return None


def _window(geometry: GridGeometry, centre: Point, radius_m: float) -> tuple[slice, slice]:
    """Row and column slices covering every cell whose centre lies within `radius_m` of `centre`.

    One cell of padding on each side absorbs rounding at the edges; empty when the disc misses the grid
    (or lies where no cell index reaches: NaN, or beyond what an index can hold).
    """
    try:
        row0, col0 = geometry.world_to_cell(centre[0] - radius_m, centre[1] - radius_m)
        row1, col1 = geometry.world_to_cell(centre[0] + radius_m, centre[1] + radius_m)
    except (OverflowError, ValueError):  # floor of inf or NaN
        return slice(0, 0), slice(0, 0)
    rows = slice(min(max(0, row0 - 1), geometry.rows), max(0, min(geometry.rows, row1 + 2)))
    cols = slice(min(max(0, col0 - 1), geometry.cols), max(0, min(geometry.cols, col1 + 2)))
    return rows, cols


def frontier_points(inputs: MenuInputs) -> list[tuple[Point, float]]:
    """A reachable target point per frontier cluster (`llmnav.mapping.frontiers`) and the cluster's length [m].

    With a static map the point is the cluster cell nearest its centroid (free, on the frontier). Sensed,
    unknown space is inflated, so no frontier cell is free: the point is the free cell within the
    inflation plus `FRONTIER_GOAL_BAND_M` of the cluster that lies nearest its centroid.
    """
    grid, lidar_map, pose = inputs.grids[0], inputs.lidar_map, inputs.pose
    free = None if inputs.sensed else lidar_map.free & ~grid.blocked
    labels = frontier_clusters(lidar_map, inputs.cfg.frontier_min_cells, free)
    targets = goal_cells(labels, grid, grid.inflation_m + FRONTIER_GOAL_BAND_M) if inputs.sensed else labels
    cells = np.bincount(labels.ravel())  # [cells] per cluster label
    resolution = grid.geometry.resolution
    # (a target cell holds its cluster's label)
    found = [
        (grid.geometry.cell_to_world(row, col), float(cells[targets[row, col]]) * resolution)
        for row, col in _nearest_to_centroids(labels, targets)
    ]
    found.sort(key=lambda item: pose.distance_to(*item[0]))
    return found


def _nearest_to_centroids(labels: np.ndarray, targets: np.ndarray) -> list[tuple[int, int]]:
    """Per cluster of `labels` (ascending), its cell in `targets` nearest the cluster's centroid.

    First in row-major order among equals; clusters without target cells are left out. One pass over
    the grid for all clusters: the sums of whole cell indices are exact, so the centroids and distances
    are the same floats a per-cluster `mean` gives.
    """
    rows, cols = np.nonzero(labels)
    ids = labels[rows, cols]
    size = int(max(labels.max(initial=0), targets.max(initial=0))) + 1
    count = np.bincount(ids, minlength=size)
    centre_r = np.bincount(ids, weights=rows, minlength=size) / np.maximum(count, 1)
    centre_c = np.bincount(ids, weights=cols, minlength=size) / np.maximum(count, 1)
    rows_t, cols_t = np.nonzero(targets)
    owner = targets[rows_t, cols_t]
    keep = count[owner] > 0  # a target cell of no cluster (none from `goal_cells`) is no one's
    rows_t, cols_t, owner = rows_t[keep], cols_t[keep], owner[keep]
    if owner.size == 0:
        return []
    distance = (rows_t - centre_r[owner]) ** 2 + (cols_t - centre_c[owner]) ** 2
    order = np.lexsort((distance, owner))  # by cluster, then distance; stable: row-major among ties
    owner = owner[order]
    first = order[np.concatenate(([True], owner[1:] != owner[:-1]))]
    return [(int(r), int(c)) for r, c in zip(rows_t[first], cols_t[first], strict=True)]


def where(pose: Pose2D, point: Point) -> str:
    """'3 m front-left' from the robot's point of view.

    Coarse on purpose: the navigation stack does the driving, so the model only needs to tell options
    apart, and every digit is a token of its own (whole metres; one decimal below 1 m).
    """
    bearing = math.degrees(pose.bearing_to(*point))
    sector = SECTORS[round(bearing / 45.0) % 8]
    distance = pose.distance_to(*point)
    return f"{distance:.1f} m {sector}" if distance < 0.95 else f"{distance:.0f} m {sector}"
