"""The waypoint planner (source B, docs/sources.md B), everything about it in one package.

- `planner`: the planner itself: its pipeline, map rules, answer models, options and oracle;
- `command`: its own `llmnav plan` command, registered through the `llmnav.commands` entry points;
- `figure`: the figure of a plan that `llmnav plan` draws.

The three sit at different heights of the import layers (the command drives whole episodes, above the
runner), so this package imports none of them: `llmnav.planners.waypoints.planner` is the planner.
"""
