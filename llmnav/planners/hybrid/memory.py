"""The hybrid planner's memory across decisions: the landmarks it knows, where it has been, what it was refused.

Landmarks come from detections (range and bearing, placed from the pose the planner believes) or, with a
published map, from the map up front. Sensed: each landmark is the mean of its estimates so far, so noise
averages out as it is seen again. Otherwise the latest estimate stands, and a published map's position is
never replaced.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from llmnav.core.geometry import Point, Pose2D
from llmnav.nav.localize import Localizer

if TYPE_CHECKING:
    from llmnav.planners.base import EpisodeContext
    from llmnav.sim.sensors import Detection


@dataclass
class Memory:
    """What the planner knows across decisions."""

    landmarks: dict[str, Point] = field(default_factory=dict)  # id -> estimated position [m]
    labels: dict[str, str] = field(default_factory=dict)  # id -> the name the detector (or map) gives it
    sightings: dict[str, tuple[float, float, int]] = field(default_factory=dict)  # id -> (sum x, sum y, n)
    visited: set[str] = field(default_factory=set)
    wanted: set[str] = field(default_factory=set)  # objects the task names
    scans: int = 0  # full turns made so far
    scanned_at: Point | None = None  # [m] where the last full turn was made
    explored: list[Point] = field(default_factory=list)  # [m] frontier goals reached
    # id -> [m] the closest spot to a landmark the motion layer let the robot reach (it refused the rest)
    closest: dict[str, Point] = field(default_factory=dict)
    refused: dict[str, Point] = field(default_factory=dict)  # id -> [m] where a trip was refused
    # refused twice from the same spot, far from it, or no path on the map: until the next frontier is explored
    unreachable: set[str] = field(default_factory=set)
    # [m] frontier goals with no path on the map: left off the menu until the next frontier is explored
    no_path: list[Point] = field(default_factory=list)
    last_result: str = "nothing yet"
    # sensed: corrects odometry by matching scans to the LiDAR map (None: odometry is believed as it is)
    localizer: Localizer | None = None

    def reached_frontier(self, goal: Point) -> None:
        """Note an explored frontier.

        The map grew: a landmark or frontier that had no path may have one now (seen through a doorway
        whose floor was still unknown), so both are offered again.
        """
        self.explored.append(goal)
        self.unreachable.clear()
        self.no_path.clear()

    def label(self, object_id: str) -> str:
        """The landmark's name (its id when none is known)."""
        return self.labels.get(object_id, object_id)


def start_memory(ctx: EpisodeContext) -> Memory:
    """The memory at the start of an episode.

    Empty when sensed; else the scenario's names (and, with a published map, every labelled object's
    goal point).
    """
    # deferred: llmnav.world.tasks brings yaml (about 0.02 s), only when an episode starts
    from llmnav.world.tasks import named_objects

    if ctx.information == "sensed":
        return Memory(localizer=Localizer() if ctx.options.localize else None)
    scenario = ctx.scenario
    wanted = {o.id for o in named_objects(scenario, ctx.task.text)} if relevance_order(ctx) else set()
    memory = Memory(wanted=wanted, labels={o.id: o.label for o in scenario.objects})
    if scenario.corridors:  # a published map: every labelled object is known up front
        memory.landmarks = {o.id: o.goal_point for o in scenario.objects}
    return memory


def relevance_order(ctx: EpisodeContext) -> bool:
    """Whether the menu is ordered by name matching against the task (`--menu-order relevance`)."""
    return ctx.options.menu_order == "relevance"


def believed_pose(ctx: EpisodeContext, memory: Memory) -> Pose2D:
    """Where the planner believes the robot is.

    Sensed: odometry, corrected by the localizer when there is one (map frame); else the true pose.
    """
    if ctx.information != "sensed":
        return ctx.world.robot.pose()
    odom = ctx.world.robot.odom()
    return memory.localizer.pose(odom) if memory.localizer is not None else odom


def in_odometry_frame(ctx: EpisodeContext, memory: Memory, x: float, y: float) -> tuple[float, float]:
    """A point [m] of the believed (map) frame in the odometry frame the motion layer drives in.

    Without a localizer the two frames are one and the point is returned as it is.
    """
    if ctx.information != "sensed" or memory.localizer is None:
        return x, y
    odom = ctx.world.robot.odom()
    return memory.localizer.pose(odom).carry(x, y, odom)


def remember(ctx: EpisodeContext, memory: Memory, pose: Pose2D, detections: list[Detection]) -> set[str]:
    """Add detections seen from `pose` to the landmark memory; the ids it did not know before."""
    # deferred: llmnav.world.tasks brings yaml (about 0.02 s), only when detections arrive
    from llmnav.world.tasks import names_in_text

    new: set[str] = set()
    for det in detections:
        oid = det.object_id
        if oid not in memory.landmarks:
            new.add(oid)
        seen = pose.point_at(math.radians(det.bearing_deg), det.distance_m)
        if ctx.information == "sensed":
            sx, sy, n = memory.sightings.get(oid, (0.0, 0.0, 0))
            memory.sightings[oid] = (sx + seen[0], sy + seen[1], n + 1)
            memory.landmarks[oid] = ((sx + seen[0]) / (n + 1), (sy + seen[1]) / (n + 1))
            memory.labels.setdefault(oid, det.label)
            if relevance_order(ctx) and names_in_text([det.label], ctx.task.text):
                memory.wanted.add(oid)
        elif oid in new or not ctx.scenario.corridors:
            memory.landmarks[oid] = seen
    return new


def look(ctx: EpisodeContext, memory: Memory) -> set[str]:
    """Run the detector; the landmarks the planner did not know that came into view."""
    return remember(ctx, memory, believed_pose(ctx, memory), ctx.world.detector.detect())
