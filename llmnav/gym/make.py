"""One environment built from its kind and keywords: the entry point every registered id calls."""

from __future__ import annotations

from typing import Any, Literal

import gymnasium

from llmnav.gym.env import FactoryEnv, NavEnv, VelocityEnv
from llmnav.gym.text_space import TaskText
from llmnav.gym.wrappers import SafetyVeto


def make_env(
    kind: Literal["factory", "velocity"],
    *,
    safety_veto: bool = True,
    render_mode: str | None = None,
    array_id: str | None = None,
    **kwargs: Any,
) -> gymnasium.Env[Any, Any]:
    """Build one environment (the entry point `gymnasium.make` calls), safety-vetoed unless told otherwise.

    `array_id`: the array-only id that errors about the text field should name (set by the registry).
    """
    env: NavEnv = (FactoryEnv if kind == "factory" else VelocityEnv)(render_mode=render_mode, **kwargs)
    space = env.observation_space
    if isinstance(space, gymnasium.spaces.Dict) and isinstance(space.spaces.get("task"), TaskText):
        space.spaces["task"].array_id = array_id  # type: ignore[attr-defined]
    return SafetyVeto(env) if safety_veto else env
