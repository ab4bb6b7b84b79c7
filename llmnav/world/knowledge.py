"""The information model: what a planner may know about the world, declared per planner, logged per run.

- `map`: a published map of corridors and labelled objects (walls, objects and their positions), as in
  the waypoint source. The default wherever a scenario publishes corridors (unless its
  `default_information` says otherwise: the maze lists its corridors for reference, but its robot gets
  no map).
- `sensed`: only what the robot's own sensors gave it. The planner receives a scenario view without
  walls, obstacles, labelled objects, corridors or tasks (only the name, extent, robot and sensor
  settings), so object positions cannot be read; its pose is odometry, its obstacles come from its own
  LiDAR map, its landmarks from detections. The default wherever no map is published (factory, maze).
- `oracle`: ground truth (the oracle baseline; planners that read true positions for their own logic).

A baseline that plans on the true map whatever it senses (`Planner.knows_map`: the oracle, frontier
exploration's final leg) keeps the whole scenario under `sensed`; only its pose is then sensed (odometry
corrected by scan matching), so its pose error can be measured like any planner's.

Scoring always reads ground truth; this module only decides what the planner is handed.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, get_args

from llmnav.errors import BadInputError
from llmnav.planners.base import Information, planner_class

if TYPE_CHECKING:
    from llmnav.world.scenario import Scenario

INFORMATION_MODES: tuple[Information, ...] = get_args(Information)


def planner_modes(planner: str) -> tuple[Information, ...]:
    """The information modes a planner can run with: its own declaration (`Planner.information_modes`)."""
    return planner_class(planner).information_modes


def default_information(planner: str, scenario: Scenario) -> Information:
    """`map` where the scenario publishes one and the planner reads it, else the planner's first mode."""
    modes = planner_modes(planner)
    published = scenario.default_information or ("map" if scenario.corridors else "sensed")
    if published == "map" and "map" in modes:
        return "map"
    return modes[0]


def resolve_information(planner: str, scenario: Scenario, requested: str | None) -> Information:
    """The mode an episode runs with; bad input (unknown, unsupported, no map published) raises."""
    if requested is None:
        return default_information(planner, scenario)
    if requested not in INFORMATION_MODES:
        raise BadInputError(f"--information {requested!r}: expected one of {', '.join(INFORMATION_MODES)}")
    modes = planner_modes(planner)
    if requested not in modes:
        raise BadInputError(f"--information {requested}: the {planner} planner runs with {', '.join(modes)}")
    if requested == "map" and (not scenario.corridors or scenario.default_information == "sensed"):
        raise BadInputError(f"--information map: scenario '{scenario.name}' publishes no map")
    mode: Information = requested  # narrowed by the membership test above
    return mode


def scenario_view(scenario: Scenario, information: Information, *, knows_map: bool = False) -> Scenario:
    """The scenario as a planner with this information may see it (see the module docstring).

    `knows_map`: the planner is a baseline that plans on the true map in every mode (`Planner.knows_map`).
    """
    if information != "sensed" or knows_map:
        return scenario
    return scenario.model_copy(update={"walls": [], "obstacles": [], "objects": [], "corridors": [], "tasks": []})
