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
"""

from __future__ import annotations

from typing import Any, Literal

import gymnasium

from llmnav.gym.env import FactoryEnv, NavEnv, VelocityEnv
from llmnav.gym.flat import DiscreteFactoryActions, NumericObservation, make_sb3
from llmnav.gym.wrappers import RunLog, SafetyVeto, TextObservation, observation_text

__all__ = [
    "DiscreteFactoryActions",
    "FactoryEnv",
    "NavEnv",
    "NumericObservation",
    "RunLog",
    "SafetyVeto",
    "TextObservation",
    "VelocityEnv",
    "make_env",
    "make_sb3",
    "observation_text",
]

ENV_IDS: tuple[str, ...] = ("llmnav/Factory-v0", "llmnav/Corridor-v0", "llmnav/Maze-v0")


def make_env(
    kind: Literal["factory", "velocity"], *, safety_veto: bool = True, render_mode: str | None = None, **kwargs: Any
) -> gymnasium.Env[Any, Any]:
    """Build one environment (the entry point `gymnasium.make` calls), safety-vetoed unless told otherwise."""
    env: NavEnv = (FactoryEnv if kind == "factory" else VelocityEnv)(render_mode=render_mode, **kwargs)
    return SafetyVeto(env) if safety_veto else env


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
    for env_id, kwargs in defaults.items():
        if env_id not in gymnasium.registry:
            gymnasium.register(id=env_id, entry_point="llmnav.gym:make_env", kwargs=kwargs)


_register()
