"""Gymnasium environments of llmnav's worlds; importing this module registers them.

    import gymnasium, llmnav.gym
    env = gymnasium.make("llmnav/Factory-v0", task_id="T1", start_pose=2)

(`gymnasium.make("llmnav.gym:llmnav/Factory-v0")` imports the module itself.)

- `llmnav/Factory-v0`: the factory (stepwise source), information `sensed`; FRONT/BACK [m],
  ROTATE_LEFT/ROTATE_RIGHT [deg], COMPLETE.
- `llmnav/Corridor-v0`: `corridor_a` (or `scenario="corridor_b"` / `"corridor_c"`), information `map`;
  (v, w) held for 100 ms.
- `llmnav/Maze-v0`: the traffic-sign maze (FSM source), information `sensed`; (v, w) held for 20 ms (50 Hz).

Every keyword of `llmnav.gym.env.EnvOptions` may be passed to `make` (scenario, task_id or task_text,
start_pose, information, lidar_sectors, max_steps, reward, ...). `make` wraps the environment in
`SafetyVeto`; `safety_veto=False` removes it deliberately.

`llmnav.gym.make_sb3(id, **options)` gives the same environment with array-only spaces, as
Stable-Baselines3 takes them (`llmnav.gym.flat`). `gymnasium.make_vec` works for every id in both
vector modes.

Array-only ids, for Stable-Baselines3's `make_vec_env`, `check_env` and `PPO("MlpPolicy", id)`: the same
worlds with the observation one float32 `Box` (no task text) and an array action (`llmnav.gym.flat`):
- `llmnav/Factory-Flat-v0`: `Factory-v0` with LiDAR and detections, the action `DiscreteFactoryActions`.
- `llmnav/Corridor-Flat-v0`: `Corridor-v0` with LiDAR and the goal (`observe_goal`: the map's target from
  the odometry pose), (v, w) in [-1, 1] (`velocity_actions="discrete"`: `DiscreteVelocityActions`).
- `llmnav/Maze-Flat-v0`: `Maze-v0` with LiDAR and detections (the signs), (v, w) as for the corridor.
They take the same keywords (`sensing=("lidar", "image")` puts the camera back, flattened). Given a text
id, SB3's vector helpers raise `BadInputError` naming the Flat id instead of a bare `TypeError`.
"""

from __future__ import annotations

from typing import Any

import gymnasium

from llmnav.gym.env import FactoryEnv, NavEnv, VelocityEnv
from llmnav.gym.flat import (
    FLAT_SUFFIX,
    DiscreteFactoryActions,
    DiscreteVelocityActions,
    FlatObservation,
    NumericObservation,
    make_flat_env,
    make_sb3,
)
from llmnav.gym.make import make_env
from llmnav.gym.wrappers import RunLog, SafetyVeto, TextObservation, observation_text

__all__ = [
    "DiscreteFactoryActions",
    "DiscreteVelocityActions",
    "FactoryEnv",
    "FlatObservation",
    "NavEnv",
    "NumericObservation",
    "RunLog",
    "SafetyVeto",
    "TextObservation",
    "VelocityEnv",
    "make_env",
    "make_flat_env",
    "make_sb3",
    "observation_text",
]

ENV_IDS: tuple[str, ...] = ("llmnav/Factory-v0", "llmnav/Corridor-v0", "llmnav/Maze-v0")
FLAT_IDS: tuple[str, ...] = tuple(i.removesuffix("-v0") + FLAT_SUFFIX for i in ENV_IDS)


def _register() -> None:
    defaults: dict[str, dict[str, Any]] = {
        "llmnav/Factory-v0": {"kind": "factory", "scenario": "factory", "information": "sensed", "max_steps": 30},
        "llmnav/Corridor-v0": {
            "kind": "velocity",
            "scenario": "corridor_a",
            "information": "map",
            "control_dt_s": 0.1,
            "max_steps": 3000,
            "arrive_radius_m": 0.5,
        },
        "llmnav/Maze-v0": {
            "kind": "velocity",
            "scenario": "maze_arena",
            "information": "sensed",
            "control_dt_s": 0.02,
            "max_steps": 15000,
            "arrive_radius_m": 0.6,
        },
    }
    # What the array-only ids add: senses that flatten to a short vector (the camera is 57 600 numbers),
    # and in the corridors, whose map the agent is given, the target that map shows.
    flat_extras: dict[str, dict[str, Any]] = {
        "llmnav/Factory-v0": {"sensing": ("lidar", "detections")},
        "llmnav/Corridor-v0": {"sensing": ("lidar",), "observe_goal": True},
        "llmnav/Maze-v0": {"sensing": ("lidar", "detections")},
    }
    for (env_id, kwargs), flat_id in zip(defaults.items(), FLAT_IDS, strict=True):
        if env_id not in gymnasium.registry:
            gymnasium.register(id=env_id, entry_point="llmnav.gym:make_env", kwargs={**kwargs, "array_id": flat_id})
        if flat_id not in gymnasium.registry:
            gymnasium.register(
                id=flat_id, entry_point="llmnav.gym:make_flat_env", kwargs={**kwargs, **flat_extras[env_id]}
            )


_register()
