"""Stable-Baselines3 and Gymnasium's vector environments on llmnav's environments, as their users call them."""

from __future__ import annotations

import importlib.util
import math
import re
import warnings
from pathlib import Path
from types import ModuleType
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium import spaces
from stable_baselines3 import PPO
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import llmnav.gym
from llmnav.errors import BadInputError
from llmnav.gym import DiscreteFactoryActions, FactoryEnv, make_sb3

EXAMPLE = Path(__file__).parents[2] / "examples" / "train_ppo.py"


@pytest.mark.parametrize("env_id", llmnav.gym.ENV_IDS)
def test_sb3_check_env_accepts_make_sb3_without_a_warning(env_id: str) -> None:
    env = make_sb3(env_id, task_index=True)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # SB3 warns about spaces it handles badly; none may remain
            sb3_check_env(env)
        assert not any(isinstance(s, spaces.Text) for s in env.observation_space.spaces.values())
        assert all(len(s.shape or ()) in (0, 1, 3) for s in env.observation_space.spaces.values())
    finally:
        env.close()


def test_the_raw_env_is_what_sb3_refuses() -> None:
    # the reason for the wrappers: SB3 rejects the Text field of every raw observation
    env = gym.make("llmnav/Corridor-v0")
    try:
        with pytest.raises(AssertionError, match="task"):
            sb3_check_env(env, warn=False)
    finally:
        env.close()


def test_factory_table_turns_each_index_into_its_command() -> None:
    env = make_sb3("llmnav/Factory-v0", task_id="T1", start_pose=2, sensing=("lidar",), safety_veto=False)
    try:
        assert isinstance(env, DiscreteFactoryActions)
        names = [f"{c} {a:g}" if c != "COMPLETE" else c for c, a in env.table]
        assert names == [
            "FRONT 0.5", "FRONT 1", "FRONT 2", "FRONT 3", "BACK 0.5", "BACK 1",
            "ROTATE_LEFT 15", "ROTATE_LEFT 30", "ROTATE_LEFT 45", "ROTATE_LEFT 90",
            "ROTATE_RIGHT 15", "ROTATE_RIGHT 30", "ROTATE_RIGHT 45", "ROTATE_RIGHT 90", "COMPLETE",
        ]  # fmt: skip
        assert env.action_space == spaces.Discrete(15)
        env.reset(seed=0)
        base = env.unwrapped
        start = base.world.robot.pose()
        env.step(np.int64(names.index("FRONT 1")))
        moved = base.world.robot.pose()
        assert math.hypot(moved.x - start.x, moved.y - start.y) == pytest.approx(1.0, abs=0.1)
        env.step(np.int64(names.index("ROTATE_LEFT 90")))
        turned = base.world.robot.pose()
        assert math.degrees(turned.yaw - moved.yaw) % 360 == pytest.approx(90.0, abs=3.0)
        terminated = env.step(np.int64(names.index("COMPLETE")))[2]
        assert terminated
        with pytest.raises(BadInputError):
            env.action(15)
    finally:
        env.close()


def test_factory_table_keeps_within_the_step_limit() -> None:
    env = DiscreteFactoryActions(FactoryEnv(max_step_m=1.5, sensing=("lidar",)))
    try:
        assert max(a for c, a in env.table if c == "FRONT") == 1.0
    finally:
        env.close()


def test_task_index_follows_the_task_a_reset_names() -> None:
    env = make_sb3("llmnav/Factory-v0", task_index=True, sensing=("lidar",))
    try:
        ids = [t.id for t in env.unwrapped.scenario.tasks]
        obs, _ = env.reset(seed=0, options={"task_id": "T3"})
        assert int(obs["task_index"]) == ids.index("T3") and ids.index("T3") > 0
        obs, _ = env.reset(seed=0, options={"task_id": "T1"})
        assert int(obs["task_index"]) == ids.index("T1")
        assert "task" not in obs
    finally:
        env.close()


def test_velocity_action_is_rescaled_to_the_robots_limits() -> None:
    env = make_sb3("llmnav/Maze-v0", sensing=("lidar",), safety_veto=False)
    try:
        env.reset(seed=0)
        base = env.unwrapped
        assert env.action_space == spaces.Box(-1.0, 1.0, (2,), np.float32)
        env.step(np.array([0.0, 1.0], dtype=np.float32))
        assert base._last_command == pytest.approx((0.0, base.spec_robot.max_angular), rel=1e-5)
        env.step(np.array([-1.0, 0.0], dtype=np.float32))
        assert base._last_command == pytest.approx((-base.spec_robot.max_linear, 0.0), rel=1e-5)
    finally:
        env.close()


def test_tables_are_flattened_row_by_row() -> None:
    raw = gym.make("llmnav/Factory-v0", task_id="T1", safety_veto=False)
    flat = make_sb3("llmnav/Factory-v0", task_id="T1", safety_veto=False)
    try:
        a, _ = raw.reset(seed=3)
        b, _ = flat.reset(seed=3)
        np.testing.assert_array_equal(b["sectors"], a["sectors"].reshape(-1))
        np.testing.assert_array_equal(b["detections"], a["detections"].reshape(-1))
        np.testing.assert_array_equal(b["image"], a["image"])
        assert b in flat.observation_space
    finally:
        raw.close()
        flat.close()


@pytest.mark.parametrize(
    "env_id", [pytest.param("llmnav/Factory-v0", marks=pytest.mark.slow), "llmnav/Corridor-v0", "llmnav/Maze-v0"]
)
def test_a_short_ppo_learn_runs_and_updates_the_policy(env_id: str) -> None:
    torch.set_num_threads(1)
    env = make_sb3(env_id)
    try:
        model = PPO("MultiInputPolicy", env, n_steps=32, batch_size=16, n_epochs=1, seed=0, device="cpu")
        before = [p.detach().clone() for p in model.policy.parameters()]
        model.learn(total_timesteps=32)
        assert model.num_timesteps == 32
        assert any(not torch.equal(a, b) for a, b in zip(before, model.policy.parameters(), strict=True))
    finally:
        env.close()


@pytest.mark.parametrize("mode", ["sync", "async"])
@pytest.mark.parametrize("env_id", llmnav.gym.ENV_IDS)
def test_make_vec_carries_the_task_in_both_modes(env_id: str, mode: str) -> None:
    env = gym.make_vec(env_id, num_envs=2, vectorization_mode=mode, sensing=("lidar",))
    try:
        scenario = env.unwrapped.get_attr("scenario")[0] if mode == "sync" else None
        obs, _ = env.reset(seed=0)
        first = obs["task"]
        assert len(first) == 2 and first[0] == first[1] and first[0].strip()
        if scenario is not None:
            assert first[0] == scenario.tasks[0].text
        if env_id == "llmnav/Factory-v0":  # a task named on reset reaches every observation
            obs, _ = env.reset(seed=0, options={"task_id": "T2"})
            assert obs["task"][0] != first[0] and obs["task"][0].strip()
            first = obs["task"]
        obs = env.step(env.action_space.sample())[0]
        assert tuple(obs["task"]) == tuple(first)
    finally:
        env.close()


def test_async_vector_task_without_copies_is_read_live() -> None:
    env = gym.make_vec(
        "llmnav/Factory-v0", num_envs=2, vectorization_mode="async", vector_kwargs={"copy": False}, sensing=("lidar",)
    )
    try:
        one = env.reset(seed=0, options={"task_id": "T1"})[0]["task"]
        t1 = tuple(one)
        two = env.reset(seed=0, options={"task_id": "T2"})[0]["task"]
        assert tuple(two) != t1 and all(t.strip() for t in two)
    finally:
        env.close()


def test_one_render_serves_the_image_and_the_detections() -> None:
    # at the detector's resolution the env renders once with the mask; it must see what two renders see
    both = gym.make("llmnav/Factory-v0", task_id="T1", safety_veto=False)
    apart = gym.make("llmnav/Factory-v0", task_id="T1", safety_veto=False, sensing=("lidar", "detections"))
    try:
        a, _ = both.reset(seed=5)
        b, _ = apart.reset(seed=5)
        assert a["detection_mask"].sum() > 0
        for key in ("detections", "detection_class", "detection_mask", "lidar"):
            np.testing.assert_array_equal(a[key], b[key])
        np.testing.assert_array_equal(a["image"], apart.unwrapped.world.camera.capture().rgb)
    finally:
        both.close()
        apart.close()


def _example() -> ModuleType:
    spec = importlib.util.spec_from_file_location("train_ppo", EXAMPLE)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_train_ppo_example_trains_saves_and_evaluates(tmp_path: Path, capsys: Any) -> None:
    torch.set_num_threads(1)
    out = tmp_path / "policy.zip"
    args = ["--timesteps", "32", "--n-steps", "32", "--max-steps", "10", "--episodes", "2", "--out", str(out)]
    code = _example().main(args)
    assert code == 0 and out.stat().st_size > 0
    captured = capsys.readouterr()
    assert re.search(r"success [0-2]/2 evaluation episodes", captured.out), captured.out
    assert re.search(r"trained 32 steps in \d+ s \(\d+ steps/s, load \d", captured.err), captured.err
    assert PPO.load(out, device="cpu").num_timesteps == 32


def test_train_ppo_example_evaluates_on_seeded_random_starts() -> None:
    # the evaluation episodes start apart (random starts), and the same seeds give the same episodes
    module = _example()
    env = module.make_env(max_steps=3)
    try:
        model = PPO("MlpPolicy", env, n_steps=16, batch_size=16, seed=0, device="cpu")
        first = module.evaluate(model, env, 3)
        again = module.evaluate(model, env, 3)
        assert [f["distance_m"] for f in first] == [f["distance_m"] for f in again]
        assert len({f["distance_m"] for f in first}) == 3
    finally:
        env.close()


def test_train_ppo_example_refuses_bad_sensing(capsys: Any) -> None:
    assert _example().main(["--sensing", "sonar"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--sensing" in err
