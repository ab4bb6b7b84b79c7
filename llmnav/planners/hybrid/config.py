"""The hybrid planner's numbers, read by its menu, its executor and the planner itself."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class HybridConfig:
    """Numbers of the hybrid planner."""

    approach_min_m: float = 0.8  # [m] closest stand-off to an object without a goal point
    approach_max_m: float = 1.8  # [m] farthest stand-off (inside the score's 2.5 m full-credit radius)
    # [m] a landmark the motion layer will not let the robot approach further counts as reached within
    # this: the stepwise source's instruction to stop 1.5-2.5 m from the target
    stop_within_m: float = 2.5
    leg_max_m: float = 1.5  # [m] longest straight leg between veto checks and detector looks
    # Options offered per decision: a short menu keeps every decision within ~120 new prompt tokens and
    # is an easier choice; farther landmarks come back into the menu as the robot moves.
    max_landmarks: int = 4
    max_frontiers: int = 2  # frontiers offered, the most useful first (`menu.frontier_utility`)
    max_frontiers_scored: int = 6  # scored decisions read no prompt: more frontiers, each weighed by its description
    describe_radius_m: float = 3.0  # [m] landmarks this close to a frontier describe it (about a room's half-width)
    describe_max: int = 3  # landmark names in a description (the nearest)
    between_max_m: float = 6.0  # [m] two landmarks farther apart than this name no place between them
    max_relational: int = 16  # relational places offered to a scored decision (the nearest)
    min_hop_m: float = 1.0  # [m] a frontier nearer than this shows next to nothing new: not offered
    frontier_decay_per_m: float = 0.2  # [1/m] how fast a frontier's worth falls with the drive to it
    frontier_min_cells: int = 12  # smaller frontier clusters are noise
    # [m] the preferred planning grid keeps the robot's corners this far off walls both ways (a clearance
    # of hypot(r + c, r + c) - r plus a cell beyond a robot of radius r); the plain grid's 0.10 m is the
    # fallback where it has no path or stand point
    roomy_corner_m: float = 0.05
    turn_first_rad: float = 0.087  # [rad] a leg further off the heading is turned toward before it is checked
    unexpected_m: float = 0.10  # [m] LiDAR hits farther than this from every known solid are obstacles
    # [m] extra clearance around such hits: the LiDAR sees only an obstacle's near face, not its depth
    unseen_depth_m: float = 0.25
    obstacle_stop_m: float = 0.35  # [m] go_to stops when something is this close ahead
    # [tokens] the option number comes first and is complete after ~6 tokens; the cap keeps the reasoning
    # short (the guard closes a cut-off string), which on a loaded CPU saves seconds per decision
    max_tokens: int = 16
    arrived_m: float = 0.3  # [m] within this of a visited landmark's stand point the robot is "there"
    rescan_m: float = 1.0  # [m] a full turn within this of the last one shows nothing new: not offered
