"""Procedurally generated buildings (flats, offices, warehouses) as scenario files, and the checker of any scenario.

`generate.generate(Request(kind, seed))` makes a building after ProcTHOR's recipe (layout, doorways, objects
by room type) and its tasks; `check.check_file(path)` tests what a scenario promises a robot (clear start
poses, reachable targets, targets out of sight). Modules: `catalogue` (objects), `kinds` (room types and
building kinds), `layout` (rooms, doorways, walls), `furnish` (placement), `sightlines` (line of sight),
`check`, `tasks` (tasks and start poses), `emit` (YAML text), `generate`, `suite` (suites for sweeps).
"""
