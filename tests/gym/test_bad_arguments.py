"""Bad arguments to the Gymnasium environments: one-line BadInputErrors, never pydantic's page or PyBullet's."""

from __future__ import annotations

import gymnasium
import pytest

import llmnav.gym  # noqa: F401 - registers the environments
from llmnav.errors import BadInputError


@pytest.mark.parametrize(
    ("kwargs", "field"), [({"start_pose": 0}, "start_pose"), ({"max_steps": 0}, "max_steps"), ({"bogus": 1}, "bogus")]
)
def test_make_refuses_bad_keywords_in_one_line(kwargs: dict, field: str) -> None:
    with pytest.raises(BadInputError) as caught:
        gymnasium.make("llmnav/Factory-v0", **kwargs)
    assert str(caught.value).startswith(f"make(): {field}:") and "\n" not in str(caught.value)


def test_reset_options_must_be_a_dict_and_a_closed_env_refuses_steps() -> None:
    env = gymnasium.make("llmnav/Factory-v0", image_width=16, image_height=16)
    try:
        with pytest.raises(BadInputError, match="must be a dict"):
            env.reset(options="x")  # type: ignore[arg-type]
        env.reset(seed=0)
        action = env.action_space.sample()
    finally:
        env.close()
    with pytest.raises(BadInputError, match="closed"):
        env.step(action)
    with pytest.raises(BadInputError, match="closed"):
        env.reset()
