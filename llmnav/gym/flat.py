"""Array-only spaces for learners that take nothing but numbers (Stable-Baselines3 and the like).

- `NumericObservation`: the observation `Dict` without its `Text` field `task`, the tables (`sectors`,
  `detections`) flattened row by row to vectors; with `task_index=True` the task becomes `task_index`, a
  `Discrete` index into the scenario's task list (fixed per task id).
- `DiscreteFactoryActions`: `Factory-v0`'s `Dict` action as one `Discrete` table of (command, amount)
  pairs, the step sizes the stepwise source asks a model to prefer (moves of 0.5–3 m, turns of 15–90°).
- `DiscreteVelocityActions`: a velocity action as one `Discrete` table of (v, w) fractions of the robot's
  limits, (0, 0) among them: a stochastic policy stops (and so can arrive) on one index, which a Gaussian
  over [-1, 1]² all but never samples within the 1 % band that counts as stopped.
- `FlatObservation`: the numeric `Dict` as one float32 `Box` vector (fields in the Dict's order, `Discrete`
  and `MultiDiscrete` fields one-hot), for `PPO("MlpPolicy", ...)`; `fields` says where each one lies.
- `make_sb3(env_id, **options)`: `gymnasium.make` plus the numeric observation and an array action (a
  velocity rescaled to [-1, 1], or the discrete table), so SB3's `check_env` passes without a warning and
  `PPO("MultiInputPolicy", env)` takes the environment as it is.
- `make_flat_env`: the entry point of the registered `llmnav/*-Flat-v0` ids, array-only from
  `gymnasium.make` on, so SB3's `make_vec_env("llmnav/Corridor-Flat-v0")` works as for any Gymnasium id.

SB3 refuses `Text` (its buffers hold arrays only) and any `Dict` action; the guard and the safety veto
stay in place under every wrapper.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Literal

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.wrappers import RescaleAction

from llmnav.errors import BadInputError
from llmnav.gym.env import FactoryEnv, VelocityEnv
from llmnav.gym.make import make_env
from llmnav.gym.wrappers import _base

MOVES_M: tuple[float, ...] = (0.5, 1.0, 2.0, 3.0)  # FRONT sizes; BACK takes the two shortest
TURNS_DEG: tuple[float, ...] = (15.0, 30.0, 45.0, 90.0)  # each way
SPEED_FRACTIONS: tuple[float, ...] = (0.0, 0.5, 1.0)  # [-] of max_linear: stop, half, full ahead
TURN_FRACTIONS: tuple[float, ...] = (-1.0, -0.5, 0.0, 0.5, 1.0)  # [-] of max_angular, left positive
VelocityActions = Literal["box", "discrete"]


class NumericObservation(gym.ObservationWrapper[dict[str, Any], Any, dict[str, Any]]):
    """Drop the `task` text from the observation; optionally give the task as an integer instead."""

    def __init__(self, env: gym.Env[dict[str, Any], Any], *, task_index: bool = False) -> None:
        super().__init__(env)
        source = env.observation_space
        if not isinstance(source, spaces.Dict):
            raise BadInputError(f"NumericObservation needs a Dict observation, not {type(source).__name__}")
        fields = {k: _vector(v) for k, v in source.spaces.items() if not isinstance(v, spaces.Text)}
        self._base = _base(env)
        self._task_ids = tuple(t.id for t in self._base.scenario.tasks)
        self._task_index = task_index
        if task_index:
            if not self._task_ids:
                raise BadInputError(f"scenario {self._base.scenario.name} has no task ids to index")
            fields["task_index"] = spaces.Discrete(len(self._task_ids))
        self._keys = frozenset(fields)
        self.observation_space = spaces.Dict(fields)

    def observation(self, observation: dict[str, Any]) -> dict[str, Any]:
        """The numeric fields (and the task's index)."""
        keep = self._keys
        numeric = {k: _flatten_table(v) for k, v in observation.items() if k in keep}
        if self._task_index:
            numeric["task_index"] = np.int64(self._index())
        return numeric

    def _index(self) -> int:
        task_id = self._base.task.id
        if task_id not in self._task_ids:
            raise BadInputError(f"task {task_id!r} is not one of the scenario's tasks {list(self._task_ids)}")
        return self._task_ids.index(task_id)


def _is_table(space: spaces.Space[Any]) -> bool:
    return isinstance(space, spaces.Box) and len(space.shape) == 2


def _vector(space: spaces.Space[Any]) -> spaces.Space[Any]:
    """A 2-D `Box` (rows × columns) as the 1-D `Box` of its rows one after another; anything else as it is."""
    if not isinstance(space, spaces.Box) or not _is_table(space):
        return space
    return spaces.Box(space.low.reshape(-1), space.high.reshape(-1), dtype=space.dtype)


def _flatten_table(value: Any) -> Any:
    return value.reshape(-1) if isinstance(value, np.ndarray) and value.ndim == 2 else value


class DiscreteFactoryActions(gym.ActionWrapper[Any, np.int64, dict[str, Any]]):
    """`Factory-v0`'s action as `Discrete(n)`: index i of `table` is (command, metres or degrees).

    The table: FRONT by each of `moves_m` (within the env's `max_step_m`), BACK by the two shortest,
    ROTATE_LEFT and ROTATE_RIGHT by each of `turns_deg`, then COMPLETE.
    """

    def __init__(
        self,
        env: gym.Env[Any, dict[str, Any]],
        *,
        moves_m: Sequence[float] = MOVES_M,
        turns_deg: Sequence[float] = TURNS_DEG,
    ) -> None:
        super().__init__(env)
        base = _base(env)
        if not isinstance(base, FactoryEnv):
            raise BadInputError(f"DiscreteFactoryActions needs llmnav/Factory-v0, not {type(base).__name__}")
        limit = base.options.max_step_m
        moves = sorted(m for m in moves_m if 0 < m <= limit)
        turns = sorted(t for t in turns_deg if 0 < t <= 360)
        if not moves or not turns:
            raise BadInputError(f"moves_m need a size in (0, {limit:g}] m and turns_deg one in (0, 360]")
        self.table: tuple[tuple[str, float], ...] = (
            *(("FRONT", m) for m in moves),
            *(("BACK", m) for m in moves[:2]),
            *(("ROTATE_LEFT", t) for t in turns),
            *(("ROTATE_RIGHT", t) for t in turns),
            ("COMPLETE", 0.0),
        )
        self.action_space = spaces.Discrete(len(self.table))

    def action(self, action: Any) -> dict[str, Any]:
        """Row `action` of the table as the environment's `Dict` action."""
        index = int(np.asarray(action).reshape(-1)[0])
        if not 0 <= index < len(self.table):
            raise BadInputError(f"action {index} is not in Discrete({len(self.table)})")
        command, amount = self.table[index]

        is_move = command in ("FRONT", "BACK")
        return {
            "command": FactoryEnv.COMMANDS.index(command),
            "distance_m": np.array([amount if is_move else 0.0], dtype=np.float32),
            "angle_deg": np.array([0.0 if is_move else amount], dtype=np.float32),
        }


class DiscreteVelocityActions(gym.ActionWrapper[Any, np.int64, Any]):
    """A velocity action as `Discrete(n)`: index i of `table` is (v, w) [m/s, rad/s].

    The table: every pair of `speeds` × `turns` (fractions of `max_linear` and `max_angular`), speed-major;
    with the defaults 15 actions, index 2 = (0, 0), the stop that ends an episode at the target.
    """

    def __init__(
        self,
        env: gym.Env[Any, Any],
        *,
        speeds: Sequence[float] = SPEED_FRACTIONS,
        turns: Sequence[float] = TURN_FRACTIONS,
    ) -> None:
        super().__init__(env)
        base = _base(env)
        if not isinstance(base, VelocityEnv):
            raise BadInputError(f"DiscreteVelocityActions needs a velocity environment, not {type(base).__name__}")
        if not speeds or not turns or any(abs(f) > 1 for f in (*speeds, *turns)):
            raise BadInputError("speeds and turns need at least one fraction each, all within [-1, 1]")
        v_max, w_max = base.spec_robot.max_linear, base.spec_robot.max_angular
        self.table: tuple[tuple[float, float], ...] = tuple((v * v_max, w * w_max) for v in speeds for w in turns)
        self.action_space = spaces.Discrete(len(self.table))

    def action(self, action: Any) -> np.ndarray:
        """Row `action` of the table as the environment's (v, w) action."""
        index = int(np.asarray(action).reshape(-1)[0])
        if not 0 <= index < len(self.table):
            raise BadInputError(f"action {index} is not in Discrete({len(self.table)})")
        return np.array(self.table[index], dtype=np.float32)


class FlatObservation(gym.ObservationWrapper[np.ndarray, Any, dict[str, Any]]):
    """The numeric `Dict` observation as one float32 vector; `fields` = (name, start, stop) of each part."""

    def __init__(self, env: gym.Env[dict[str, Any], Any]) -> None:
        super().__init__(env)
        source = env.observation_space
        if not isinstance(source, spaces.Dict) or any(isinstance(s, spaces.Text) for s in source.spaces.values()):
            raise BadInputError("FlatObservation needs a numeric Dict observation (wrap NumericObservation first)")
        self._source = source
        fields, start = [], 0
        for name, space in source.spaces.items():
            size = spaces.flatdim(space)
            fields.append((name, start, start + size))
            start += size
        self.fields: tuple[tuple[str, int, int], ...] = tuple(fields)
        flat = spaces.flatten_space(source)
        assert isinstance(flat, spaces.Box)
        self.observation_space = spaces.Box(flat.low.astype(np.float32), flat.high.astype(np.float32), dtype=np.float32)

    def observation(self, observation: dict[str, Any]) -> np.ndarray:
        """The fields one after another, as float32."""
        return np.asarray(spaces.flatten(self._source, observation), dtype=np.float32)


def _array_only(env: gym.Env[Any, Any], *, task_index: bool, velocity_actions: VelocityActions) -> gym.Env[Any, Any]:
    """The numeric observation and an array action (the Factory table, a rescaled or discrete velocity)."""
    if velocity_actions not in ("box", "discrete"):
        raise BadInputError(f"velocity_actions={velocity_actions!r}: use 'box' or 'discrete'")
    env = NumericObservation(env, task_index=task_index)
    if isinstance(env.unwrapped, FactoryEnv):
        return DiscreteFactoryActions(env)
    if velocity_actions == "discrete":
        return DiscreteVelocityActions(env)
    shape: tuple[int, ...] = env.action_space.shape or (2,)
    unit = np.ones(shape, dtype=np.float32)  # float32 bounds: no precision warning
    return RescaleAction(env, -unit, unit)


def make_sb3(
    env_id: str, *, task_index: bool = False, velocity_actions: VelocityActions = "box", **options: Any
) -> gym.Env[Any, Any]:
    """`gymnasium.make(env_id, **options)` with array-only spaces, as Stable-Baselines3 takes them.

    The observation loses `task` (`task_index=True`: the task's index instead) and its tables are
    flattened; `Factory-v0`'s action becomes `DiscreteFactoryActions`, a velocity (v, w) is given in
    [-1, 1] of the robot's limits (`velocity_actions="discrete"`: `DiscreteVelocityActions`). The safety
    veto stays unless `safety_veto=False`. A `-Flat-v0` id is array-only already: it is made as it is.
    """
    if env_id.endswith(FLAT_SUFFIX):
        return gym.make(env_id, task_index=task_index, velocity_actions=velocity_actions, **options)
    return _array_only(gym.make(env_id, **options), task_index=task_index, velocity_actions=velocity_actions)


FLAT_SUFFIX = "-Flat-v0"


def make_flat_env(
    kind: Literal["factory", "velocity"],
    *,
    task_index: bool = False,
    velocity_actions: VelocityActions = "box",
    **kwargs: Any,
) -> gym.Env[Any, Any]:
    """The entry point of the `llmnav/*-Flat-v0` ids: `make_env`, array-only, the observation one vector."""
    env = _array_only(make_env(kind, **kwargs), task_index=task_index, velocity_actions=velocity_actions)
    return FlatObservation(env)
