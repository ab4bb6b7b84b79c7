"""What Stable-Baselines3 users expect of llmnav's environments: full speed is not a veto, array-only ids
that SB3's helpers take, a clear error from the text ids, seeded random starts, and RecordVideo."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces
from stable_baselines3 import PPO
from stable_baselines3.common.env_checker import check_env as sb3_check_env
from stable_baselines3.common.env_util import make_vec_env

import llmnav.gym
from llmnav.errors import BadInputError
from llmnav.gym import DiscreteVelocityActions, FlatObservation, make_sb3
from llmnav.mapping.grid import build_grid

FULL_AHEAD = np.array([1.0, 0.0], dtype=np.float32)


def test_full_speed_in_the_action_space_is_not_vetoed() -> None:
    # corridor_a's listed start faces 14 m of empty corridor: 100 steps at 0.4 m/s cover 4 m of it
    env = make_sb3("llmnav/Corridor-v0", sensing=("lidar",))
    try:
        env.reset(seed=0)
        base = env.unwrapped
        for _ in range(100):
            info = env.step(FULL_AHEAD)[4]
            assert "vetoed" not in info, info["vetoed"]
        assert info["vetoes"] == 0
        assert base._last_command == (base.spec_robot.max_linear, 0.0)
        assert base.world.robot.pose().x == pytest.approx(4.0, abs=0.2)
    finally:
        env.close()


def test_vetoes_count_the_vetoed_steps() -> None:
    # full speed toward the east wall: once the stopping distance reaches it, every step is vetoed
    env = make_sb3("llmnav/Corridor-v0", sensing=("lidar",), max_steps=400)
    try:
        env.reset(seed=0)
        vetoed = 0
        for _ in range(400):
            _, _, terminated, truncated, info = env.step(FULL_AHEAD)
            vetoed += "vetoed" in info
            assert info["vetoes"] == vetoed
            if terminated or truncated:
                break
        assert vetoed > 10 and info["collisions"] == 0
        assert env.reset(seed=0)[1]["vetoes"] == 0
    finally:
        env.close()


@pytest.mark.parametrize("env_id", llmnav.gym.FLAT_IDS)
def test_flat_ids_pass_sb3_check_env_and_make_vec_env(env_id: str) -> None:
    env = gym.make(env_id)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # SB3 warns about spaces it handles badly; none may remain
            sb3_check_env(env)
        assert isinstance(env.observation_space, spaces.Box) and env.observation_space.dtype == np.float32
        assert isinstance(env.action_space, spaces.Box | spaces.Discrete)
    finally:
        env.close()
    vec = make_vec_env(env_id, n_envs=2, seed=0)
    try:
        obs = vec.reset()
        assert obs.shape == (2, *vec.observation_space.shape) and np.isfinite(obs).all()
        obs, rewards, dones, infos = vec.step(np.array([vec.action_space.sample() for _ in range(2)]))
        assert obs.shape[0] == 2 and len(infos) == 2 and "score" in infos[0]
    finally:
        vec.close()


def test_flat_observation_fields_say_where_each_reading_is() -> None:
    env = gym.make("llmnav/Corridor-Flat-v0")
    try:
        obs, _ = env.reset(seed=0)
        flat = env.get_wrapper_attr("fields")
        names = [name for name, _, _ in flat]
        assert set(names) == {"lidar", "sectors", "odom", "goal"}
        where = {name: (start, stop) for name, start, stop in flat}
        start, stop = where["goal"]
        base = env.unwrapped
        odom = base.world.robot.odom()
        (x, y) = base.scenario.target_points(base.task)[0]
        assert obs[start] == pytest.approx(math.hypot(x - odom.x, y - odom.y), abs=1e-4)
        assert obs.shape == (flat[-1][2],)
    finally:
        env.close()


def test_a_ppo_mlp_policy_learns_on_a_flat_id() -> None:
    model = PPO("MlpPolicy", "llmnav/Corridor-Flat-v0", n_steps=32, batch_size=16, n_epochs=1, seed=0, device="cpu")
    try:
        model.learn(total_timesteps=32)
        assert model.num_timesteps == 32
    finally:
        model.get_env().close()


@pytest.mark.parametrize("env_id", llmnav.gym.ENV_IDS)
def test_text_ids_in_sb3_vector_helpers_name_the_flat_id(env_id: str) -> None:
    flat_id = env_id.replace("-v0", "-Flat-v0")
    with pytest.raises(BadInputError, match=flat_id.replace("/", "/")) as caught:
        make_vec_env(env_id, n_envs=1, env_kwargs={"sensing": ("lidar",)})
    assert "make_sb3" in str(caught.value) and "\n" not in str(caught.value)


def test_ppo_given_a_text_env_names_the_flat_id() -> None:
    env = gym.make("llmnav/Corridor-v0", sensing=("lidar",))
    try:
        with pytest.raises(BadInputError, match="llmnav/Corridor-Flat-v0"):
            PPO("MultiInputPolicy", env, device="cpu")
        # Gymnasium still sees no shape: its own checks and vectors are unchanged
        assert env.observation_space["task"].shape is None or env.observation_space["task"].shape == None  # noqa: E711
    finally:
        env.close()


def _starts(env: gym.Env, seeds: list[int]) -> list[list[float]]:
    return [env.reset(seed=s)[1]["start"] for s in seeds]


@pytest.mark.parametrize(("env_id", "scenario"), [("llmnav/Corridor-v0", None), ("llmnav/Factory-v0", "factory")])
def test_random_starts_are_seeded_and_clear_of_obstacles(env_id: str, scenario: str | None) -> None:
    env = gym.make(env_id, start="random", sensing=("lidar",))
    try:
        base = env.unwrapped
        first = _starts(env, list(range(8)))
        assert _starts(env, list(range(8))) == first  # the same seed, the same start
        assert len({tuple(p) for p in first}) == 8  # a different start per seed
        grid = build_grid(base.scenario)
        radius = base.spec_robot.radius_m
        for seed, (x, y, yaw) in enumerate(first):
            env.reset(seed=seed)
            pose = base.world.robot.pose()
            assert (pose.x, pose.y) == pytest.approx((x, y), abs=1e-3)
            assert grid.is_free(x, y) and -math.pi <= yaw <= math.pi
            assert float(np.nanmin(base.last_scan.ranges)) > radius  # nothing touches the robot
            assert base.world.motion.collisions == 0
        spread = np.ptp(np.array(first)[:, :2], axis=0)
        assert spread.max() > 1.0  # spread over the free space, not jittered around one pose
    finally:
        env.close()


def test_random_starts_keep_within_the_radius_and_reset_options_switch_modes() -> None:
    env = gym.make("llmnav/Corridor-v0", sensing=("lidar",), start_radius_m=1.5)
    try:
        listed = env.reset(seed=0)[1]["start"]
        assert listed == [0.0, 0.0, 0.0]
        drawn = env.reset(seed=1, options={"start": "random"})[1]["start"]
        assert drawn != listed and math.hypot(drawn[0], drawn[1]) <= 1.5 + 0.05
        assert env.reset(seed=2)[1]["start"] != listed  # the mode stays until changed
        assert env.reset(seed=2, options={"start_pose": 1})[1]["start"] == listed
        with pytest.raises(BadInputError, match="start="):
            env.reset(options={"start": "anywhere"})
    finally:
        env.close()


def test_goal_observation_needs_the_map_and_follows_the_odometry() -> None:
    with pytest.raises(BadInputError, match="observe_goal needs information='map'"):
        gym.make("llmnav/Maze-v0", observe_goal=True)
    env = gym.make("llmnav/Corridor-v0", sensing=("lidar",), observe_goal=True, task_id="A1")
    try:
        obs, info = env.reset(seed=0)
        goal = obs["goal"]
        assert goal in env.observation_space["goal"]
        # room 101's goal point (1.5, 1.1) from the start (0, 0) facing +x: 1.86 m at 36 deg to the left
        assert goal[0] == pytest.approx(math.hypot(1.5, 1.1), abs=1e-3)
        assert math.atan2(goal[1], goal[2]) == pytest.approx(math.atan2(1.1, 1.5), abs=1e-3)
        obs = env.step(np.array([0.0, 1.0], dtype=np.float32))[0]  # a left turn brings it nearer ahead
        assert abs(math.atan2(obs["goal"][1], obs["goal"][2])) < math.atan2(1.1, 1.5)
    finally:
        env.close()


def test_progress_reward_is_the_metres_gained_and_the_bonus() -> None:
    env = gym.make("llmnav/Corridor-v0", sensing=("lidar",), task_id="A1", reward="progress", arrive_radius_m=2.0)
    try:
        _, info = env.reset(seed=0)
        before = info["distance_m"]
        for _ in range(5):  # the burger accelerates at 1 m/s^2: 0.5 s to reach 0.4 m/s
            _, reward, _, _, info = env.step(np.array([0.4, 0.0], dtype=np.float32))
            assert reward == pytest.approx(before - info["distance_m"], abs=1e-5) and reward > 0.001
            before = info["distance_m"]
        # within score_delta's 2.5 m plateau the progress reward still pays for closing in
        _, reward, terminated, _, info = env.step(np.array([0.0, 0.0], dtype=np.float32))
        assert terminated and info["success"]
        assert reward == pytest.approx(1.0 + before - info["distance_m"], abs=1e-5)  # braking still gains
    finally:
        env.close()


def test_discrete_velocity_actions_include_the_stop() -> None:
    env = make_sb3("llmnav/Corridor-v0", sensing=("lidar",), velocity_actions="discrete")
    try:
        assert isinstance(env, DiscreteVelocityActions) and env.action_space == spaces.Discrete(15)
        base = env.unwrapped
        v_max, w_max = base.spec_robot.max_linear, base.spec_robot.max_angular
        assert env.table[2] == (0.0, 0.0) and (v_max, 0.0) in env.table and (0.0, w_max) in env.table
        env.reset(seed=0)
        env.step(np.int64(env.table.index((v_max, 0.0))))
        assert base._last_command == pytest.approx((v_max, 0.0))
        with pytest.raises(BadInputError):
            env.step(np.int64(15))
        with pytest.raises(BadInputError, match="velocity_actions"):
            make_sb3("llmnav/Corridor-v0", velocity_actions="grid")
        with pytest.raises(BadInputError, match="velocity environment"):
            DiscreteVelocityActions(gym.make("llmnav/Factory-v0", sensing=("lidar",)))
    finally:
        env.close()


def test_flat_observation_refuses_a_text_dict() -> None:
    env = gym.make("llmnav/Corridor-v0", sensing=("lidar",))
    try:
        with pytest.raises(BadInputError, match="numeric Dict"):
            FlatObservation(env)
    finally:
        env.close()


def test_the_rl_extra_installs_moviepy() -> None:
    import tomllib

    pyproject = tomllib.loads((Path(__file__).parents[2] / "pyproject.toml").read_text())
    rl = pyproject["project"]["optional-dependencies"]["rl"]
    assert any(req.startswith("moviepy") for req in rl), rl


def test_record_video_writes_an_mp4_with_moviepy(tmp_path: Path) -> None:
    import moviepy  # noqa: F401 - the `rl` extra installs it; RecordVideo needs it
    from gymnasium.wrappers import RecordVideo

    env = RecordVideo(
        gym.make("llmnav/Corridor-v0", render_mode="rgb_array", sensing=("lidar",), max_steps=12),
        str(tmp_path),
        disable_logger=True,
    )
    try:
        env.reset(seed=0)
        done = False
        while not done:
            terminated, truncated = env.step(np.array([0.4, 0.2], dtype=np.float32))[2:4]
            done = terminated or truncated
    finally:
        env.close()
    videos = list(tmp_path.glob("*.mp4"))
    assert len(videos) == 1 and videos[0].stat().st_size > 1000
