"""Waypoint planner (source B, docs/sources.md B): the model writes a JSON array of waypoints from the map facts.

Pipeline per target: ground the command in the scenario's object list (exact name first, the model picks
from the list otherwise) -> generate waypoints from corridor rectangles, robot pose and target pose ->
validate every point (inside a corridor with the margin, spacing, count, final point on the target,
segments clear of obstacles) and regenerate with the exact complaints, up to a bound -> follow them with
the P-controller (0.4 m/s, 2.0 rad/s, 0.1 m, 0.087 rad), stopping for obstacles closer than 0.5 m within
±15° ahead (emergency stop below 0.35 m) and replanning from the current pose, at most 5 times with a
5 s (sim) cooldown. Every segment passes the guarded motion layer's veto first: a segment through something
the map lacks is refused before the robot moves, and replanned around. Unlike the published code,
out-of-bounds points are never dropped silently.

Modules: `validate` (the map rules), `ground` (which object a command means), `plan` (generation, no
simulator: `llmnav plan` uses it), `execute` (the planner on the simulator), `oracle` (its answers from ground
truth, for `policy:oracle`).
"""

from llmnav.planners.waypoints.planner.execute import WaypointConfig, WaypointPlanner, map_to_odom
from llmnav.planners.waypoints.planner.ground import ground_target
from llmnav.planners.waypoints.planner.plan import (
    Attempt,
    ModelCall,
    PlanningClock,
    PlanResult,
    Point,
    generate_plan,
    plan_json,
    plan_summary,
    waypoint_schema,
)
from llmnav.planners.waypoints.planner.validate import PlanRules, validate_waypoints

__all__ = [
    "Attempt",
    "ModelCall",
    "PlanResult",
    "PlanRules",
    "PlanningClock",
    "Point",
    "WaypointConfig",
    "WaypointPlanner",
    "generate_plan",
    "ground_target",
    "map_to_odom",
    "plan_json",
    "plan_summary",
    "validate_waypoints",
    "waypoint_schema",
]
