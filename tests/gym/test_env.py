"""llmnav's Gymnasium environments: Gymnasium's own checker, seeding, the safety wrapper, run logs and text."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env, data_equivalence
from typer.testing import CliRunner

import llmnav.gym
from llmnav.backends.replay import ReplayBackend, write_script
from llmnav.cli import app
from llmnav.errors import BadInputError
from llmnav.gym import FactoryEnv, RunLog, SafetyVeto, TextObservation, VelocityEnv
from llmnav.planners.base import drive_options
from llmnav.runs.runner import EpisodeSpec, run_episode

SMALL = str(Path(__file__).parents[1] / "runner" / "small_room.yaml")


def factory_action(command: str, distance_m: float = 0.0, angle_deg: float = 0.0) -> dict[str, Any]:
    return {
        "command": FactoryEnv.COMMANDS.index(command),
        "distance_m": np.array([distance_m], dtype=np.float32),
        "angle_deg": np.array([angle_deg], dtype=np.float32),
    }


@pytest.mark.parametrize("env_id", llmnav.gym.ENV_IDS)
def test_gymnasium_env_checker_passes(env_id: str) -> None:
    env = gym.make(env_id)
    try:
        check_env(env.unwrapped)  # raises on any breach of the API contract
        assert isinstance(env.unwrapped, llmnav.gym.NavEnv)
    finally:
        env.close()


def test_make_wraps_the_safety_veto_unless_removed() -> None:
    wrapped = gym.make("llmnav/Maze-v0")
    bare = gym.make("llmnav/Maze-v0", safety_veto=False)
    try:
        layers = []
        env: Any = wrapped
        while isinstance(env, gym.Wrapper):
            layers.append(type(env))
            env = env.env
        assert SafetyVeto in layers
        env = bare
        while isinstance(env, gym.Wrapper):
            assert not isinstance(env, SafetyVeto)
            env = env.env
    finally:
        wrapped.close()
        bare.close()


def test_same_seed_same_observations_and_the_seed_reaches_the_sensors() -> None:
    # LiDAR noise on, so the world's noise streams show whether the seed reached them.
    env = FactoryEnv(task_id="T1", start_pose=2)
    env.world.lidar.config = env.world.lidar.config.model_copy(update={"noise_std_m": 0.02})
    try:
        first, _ = env.reset(seed=7)
        again, _ = env.reset(seed=7)
        other, _ = env.reset(seed=8)
        assert data_equivalence(first, again, exact=True)
        assert not np.array_equal(first["lidar"], other["lidar"])
        # the same action from the same seed lands on the same pose, bit for bit
        env.reset(seed=7)
        a = env.step(factory_action("FRONT", 1.0))[0]
        env.reset(seed=7)
        b = env.step(factory_action("FRONT", 1.0))[0]
        assert data_equivalence(a, b, exact=True)
    finally:
        env.close()


def test_observation_never_holds_the_true_pose_when_odometry_drifts() -> None:
    env = FactoryEnv(task_id="T1", start_pose=1)  # the factory's odometry drifts (its scenario file says so)
    try:
        assert env.scenario.sensors.odometry.wheel_noise_m_per_sqrt_m > 0
        env.reset(seed=0)
        obs = env.step(factory_action("FRONT", 2.0))[0]
        true = env.world.robot.pose()
        odom = env.world.robot.odom()
        assert np.allclose(obs["odom"][:2], [odom.x, odom.y], atol=1e-4)
        assert not np.allclose(obs["odom"][:2], [true.x, true.y], atol=1e-4)
    finally:
        env.close()


def _wall_ahead(env: Any, distance_m: float = 1.2) -> None:
    """Drop a 0.6 m box `distance_m` ahead of the start pose (its near face 0.3 m closer); read again."""
    base = env.unwrapped
    start = base.world.robot.pose()
    x, y = start.x + distance_m * math.cos(start.yaw), start.y + distance_m * math.sin(start.yaw)
    base.world.add_obstacle(x, y, size=0.6)
    env.reset(seed=0)


def test_vetoed_front_leaves_the_robot_where_it_was() -> None:
    env = SafetyVeto(FactoryEnv(scenario=SMALL, task_id="T1"))
    env.reset(seed=0)
    _wall_ahead(env)
    before = env.unwrapped.world.robot.pose()
    _, reward, terminated, truncated, info = env.step(factory_action("FRONT", 2.0))
    after = env.unwrapped.world.robot.pose()
    assert info["vetoes"] == 1 and "collide" in info["vetoed"]
    assert (after.x, after.y, after.yaw) == pytest.approx((before.x, before.y, before.yaw), abs=1e-6)
    assert not terminated and not truncated and reward == pytest.approx(0.0, abs=1e-9)
    # a turn is never vetoed; a short move that stops in time is allowed
    assert "vetoed" not in env.step(factory_action("FRONT", 0.3))[4]
    env.close()


def test_without_the_veto_the_same_action_collides() -> None:
    env = FactoryEnv(scenario=SMALL, task_id="T1")
    env.reset(seed=0)
    _wall_ahead(env)
    info = env.step(factory_action("FRONT", 2.0))[4]
    assert info.get("collided_with") is not None
    assert info["collisions"] >= 1
    env.close()


def test_velocity_veto_is_the_layers_time_to_collision_check() -> None:
    env = gym.make("llmnav/Maze-v0")
    try:
        env.reset(seed=0)
        # The box's near face 0.2 m ahead of the burger's centre. At 0.4 m/s the layer needs 0.4 * 0.02 m of
        # travel + 0.4^2 / (2 * 1.0 m/s^2) of braking + 0.02 m margin, plus the 0.105 m radius and 0.02 m:
        # 0.233 m > 0.2 m, so forward speed is refused. At 0.08 m/s it needs 0.15 m: allowed.
        _wall_ahead(env, 0.5)
        base = env.unwrapped
        v_max = base.spec_robot.max_linear
        assert v_max == pytest.approx(0.4)
        before = base.world.robot.pose()
        info = env.step(np.array([v_max, 0.0], dtype=np.float32))[4]
        assert info["vetoed"] and info["vetoes"] == 1
        assert any(e["type"] == "override" for e in info["guard_events"])
        assert base.world.robot.pose().distance_to(before.x, before.y) < 1e-6
        slow = env.step(np.array([0.2 * v_max, 0.0], dtype=np.float32))[4]
        assert "vetoed" not in slow
        assert base.world.robot.pose().distance_to(before.x, before.y) > 1e-4
    finally:
        env.close()


def test_runlog_episode_scores_like_the_planners_episode(tmp_path: Path) -> None:
    """The same actions from the same seed give the same final pose and S through either road."""
    actions = [("FRONT", 2.0, 0.0), ("ROTATE_RIGHT", 0.0, 30.0), ("FRONT", 1.5, 0.0), ("COMPLETE", 0.0, 0.0)]
    replies = []
    for command, metres, degrees in actions:
        body = {
            "goal": "g",
            "reasoning": "r",
            "scene_description": "s",
            "action": {"command": command, "parameters": metres or degrees},
        }
        replies.append(json.dumps(body))
    backend = ReplayBackend(write_script(tmp_path / "script", replies))
    spec = EpisodeSpec(
        scenario=SMALL,
        task_id="T1",
        options=drive_options(planner="stepwise", sensing=("lidar",), seed=0),
        backend="replay",
        out_dir=tmp_path / "planner",
        plots=False,
    )
    planner_summary = run_episode(spec, backend_obj=backend)

    env = RunLog(SafetyVeto(FactoryEnv(scenario=SMALL, task_id="T1")), tmp_path / "gym", agent="scripted")
    env.reset(seed=0)
    for command, metres, degrees in actions:
        terminated = env.step(factory_action(command, metres, degrees))[2]
    assert terminated
    env.close()
    gym_summary = json.loads((tmp_path / "gym" / "episode-0001" / "summary.json").read_text())

    assert planner_summary["outcome"] == gym_summary["outcome"] == "completed"
    assert gym_summary["final_pose"] == pytest.approx(planner_summary["final_pose"], abs=1e-6)
    assert gym_summary["score"] == pytest.approx(planner_summary["score"], abs=1e-6)
    assert gym_summary["success"] == planner_summary["success"]
    assert gym_summary["path_length_m"] == pytest.approx(planner_summary["path_length_m"], rel=0.02)

    # and `llmnav score` reads the gym's run folder like any other
    out = CliRunner().invoke(app, ["score", str(tmp_path / "gym"), "--format", "json"])
    assert out.exit_code == 0, out.output
    tables, _ = json.JSONDecoder().raw_decode(out.stdout)
    record = tables[0]["records"][0]
    assert record["task"] == "T1" and record["n"] == 1 and record["successes"] == int(gym_summary["success"])
    assert record["score"]["mean"] == pytest.approx(gym_summary["score"], abs=1e-4)


def test_runlog_closes_an_unfinished_episode_as_aborted(tmp_path: Path) -> None:
    env = RunLog(FactoryEnv(scenario=SMALL, task_id="T1"), tmp_path)
    env.reset(seed=0)
    env.step(factory_action("ROTATE_LEFT", angle_deg=45.0))
    env.reset(seed=1)  # leaves episode 1 unfinished
    env.close()
    first = json.loads((tmp_path / "episode-0001" / "summary.json").read_text())
    second = json.loads((tmp_path / "episode-0002" / "summary.json").read_text())
    assert first["outcome"] == second["outcome"] == "aborted"
    events = [json.loads(line) for line in (tmp_path / "episode-0001" / "run.jsonl").read_text().splitlines()]
    assert [e["type"] for e in events].count("action") == 1
    assert any(e["type"] == "observation" and e.get("image") for e in events)


def test_text_observation_is_the_planners_text() -> None:
    from llmnav.sensing.perception import lidar_text

    env = TextObservation(FactoryEnv(task_id="T1", start_pose=1))
    text, _ = env.reset(seed=0)
    base = env.unwrapped
    assert text in env.observation_space
    assert base.task.text in text
    assert lidar_text(base.last_scan, 8, 90.0) in text
    assert "Detected objects" in text
    env.close()


def test_reward_is_the_change_of_the_score_plus_the_bonus() -> None:
    env = FactoryEnv(scenario=SMALL, task_id="T1", start_pose=2, success_bonus=1.0)
    _, info0 = env.reset(seed=0)
    _, reward, _, _, info1 = env.step(factory_action("FRONT", 0.5))
    assert reward == pytest.approx(info1["score"] - info0["score"], abs=1e-6)
    # start pose 2 stands 2.0 m from the box: COMPLETE there succeeds and earns the bonus
    _, reward, terminated, _, info2 = env.step(factory_action("COMPLETE"))
    assert terminated and info2["success"]
    assert reward == pytest.approx(info2["score"] - info1["score"] + 1.0, abs=1e-6)
    with pytest.raises(BadInputError):
        env.step(factory_action("COMPLETE"))
    env.close()


def test_truncated_after_max_steps_and_sparse_reward() -> None:
    env = VelocityEnv(scenario="maze_arena", max_steps=3, control_dt_s=0.02, reward="sparse")
    env.reset(seed=0)
    outcomes = [env.step(np.array([0.05, 0.0], dtype=np.float32)) for _ in range(3)]
    assert [o[3] for o in outcomes] == [False, False, True]
    assert all(o[1] == 0.0 for o in outcomes)
    env.close()


def test_bad_input_is_one_clear_error() -> None:
    with pytest.raises(Exception, match="(?i)extra"):
        FactoryEnv(task_id="T1", colour="red")
    if llmnav.gym.env.human_render_problem() is not None:
        with pytest.raises(BadInputError, match="render_mode='human' needs"):
            FactoryEnv(task_id="T1", render_mode="human")
    env = FactoryEnv(task_id="T1")
    env.reset(seed=0)
    with pytest.raises(BadInputError, match="action space"):
        env.step({"command": 9, "distance_m": np.array([1.0]), "angle_deg": np.array([0.0])})
    with pytest.raises(BadInputError, match="unknown"):
        env.reset(options={"goal": "anywhere"})
    env.close()


def test_rgb_array_render_shows_top_view_and_camera() -> None:
    env = gym.make("llmnav/Factory-v0", render_mode="rgb_array", task_id="T1")
    env.reset(seed=0)
    frame = env.render()
    env.close()
    assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3
    assert frame.shape[1] > frame.shape[0]  # the camera beside the map
    assert frame.std() > 10  # not blank


def test_sensing_selects_the_observation_fields() -> None:
    env = FactoryEnv(task_id="T1", sensing=("lidar",))
    obs, _ = env.reset(seed=0)
    assert set(obs) == {"lidar", "sectors", "odom", "task"} == set(env.observation_space.spaces)
    assert obs in env.observation_space
    env.close()
