"""Reinforcement learning: PPO trained to success on the README's example, and each id's steps/s.

`python -m bench rl` (needs the `rl` extra).

- PPO to success: `examples/train_ppo.py` as it is (the corridor task, its step budget), then its
  deterministic policy on `EVAL_EPISODES` fresh episodes (seeds the training never drew); printed: the
  training steps, their wall time, successes out of the episodes and the load, against the 80 % target.
- Throughput: "raw" steps the `gymnasium.make` environment (safety veto on) with sampled actions; "raw,
  LiDAR only" drops the camera and detections; "PPO" is `make_sb3` under `PPO("MultiInputPolicy")`,
  rollouts and updates included, one torch thread (the simulation has the other core), with the env's
  default sensing and with LiDAR only.

One run each; wall time on a shared machine, so the load average is printed with the tables. Quick mode:
one 64-step PPO update and 2 short evaluation episodes, 20 raw steps and one PPO update of 32 steps a id.
"""

from __future__ import annotations

import importlib.util
import os
import time
from pathlib import Path
from types import ModuleType
from typing import Any

import gymnasium as gym

import llmnav.gym
from bench import NOT_MEASURED, judged, quick_from_env

RAW_STEPS = 300
PPO_STEPS = 512  # two PPO updates of 256 steps
QUICK_RAW_STEPS = 20
QUICK_PPO_STEPS = 32  # one update of 32 steps
EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "train_ppo.py"
EVAL_EPISODES = 50
SUCCESS_TARGET = 0.8  # [-] of the evaluation episodes
QUICK_TRAIN_STEPS = 64
QUICK_EVAL_EPISODES = 2
QUICK_EVAL_MAX_STEPS = 10


def example() -> ModuleType:
    """`examples/train_ppo.py` as a module (what the README runs)."""
    spec = importlib.util.spec_from_file_location("train_ppo", EXAMPLE)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def ppo_to_success(quick: bool = False) -> None:
    """Train the example's PPO for its step budget, evaluate it, print steps, time, successes and load."""
    recipe = example()
    steps = QUICK_TRAIN_STEPS if quick else recipe.TIMESTEPS
    episodes = QUICK_EVAL_EPISODES if quick else EVAL_EPISODES
    options = {"max_steps": QUICK_EVAL_MAX_STEPS} if quick else {}
    load_start = os.getloadavg()[0]
    env = recipe.make_env(**options)
    try:
        n_steps = steps if quick else recipe.N_STEPS
        model, seconds = recipe.train(env, steps, n_steps=n_steps)
        started = time.perf_counter()
        finals = recipe.evaluate(model, env, episodes)
        eval_seconds = time.perf_counter() - started
    finally:
        env.close()
    wins = sum(bool(f["success"]) for f in finals)
    rate = wins / len(finals)
    verdict = "meets" if rate >= SUCCESS_TARGET else "BELOW TARGET"
    print(f"[bench.rl] PPO to success: {recipe.ENV_ID}, {recipe.CORRIDOR_TASK['task_id']} from random starts")
    print(f"  training steps           {model.num_timesteps}")
    print(f"  training wall time [s]   {seconds:.0f} ({model.num_timesteps / seconds:.0f} steps/s)")
    print(f"  success                  {wins}/{len(finals)} evaluation episodes ({100 * rate:.0f} %), "
          f"target {100 * SUCCESS_TARGET:.0f} %: {judged(verdict, quick)}")  # fmt: skip
    print(f"  evaluation wall time [s] {eval_seconds:.0f}")
    print(f"  load {load_start:.1f} at the start, {os.getloadavg()[0]:.1f} at the end")


def raw_rate(env_id: str, steps: int = RAW_STEPS, **options: Any) -> float:
    """Steps per second of the raw environment with sampled actions (resets included)."""
    env = gym.make(env_id, **options)
    try:
        env.reset(seed=0)
        env.action_space.seed(0)
        started = time.perf_counter()
        for _ in range(steps):
            terminated, truncated = env.step(env.action_space.sample())[2:4]
            if terminated or truncated:
                env.reset()
        return steps / (time.perf_counter() - started)
    finally:
        env.close()


def ppo_rate(env_id: str, steps: int = PPO_STEPS, **options: Any) -> float:
    """Steps per second of PPO learning on `make_sb3(env_id)` (collection and gradient steps)."""
    import torch
    from stable_baselines3 import PPO

    torch.set_num_threads(1)
    env = llmnav.gym.make_sb3(env_id, **options)
    try:
        rollout = max(steps // 2, 32)  # [steps] a rollout: two in the full bench, one in quick mode
        batch = min(64, rollout)
        model = PPO("MultiInputPolicy", env, n_steps=rollout, batch_size=batch, n_epochs=4, seed=0, device="cpu")
        started = time.perf_counter()
        model.learn(total_timesteps=steps)
        return model.num_timesteps / (time.perf_counter() - started)
    finally:
        env.close()


def main(quick: bool = False) -> None:
    """Print the table (quick: a few steps each, not a measurement)."""
    ppo_to_success(quick)
    raw, ppo = (QUICK_RAW_STEPS, QUICK_PPO_STEPS) if quick else (RAW_STEPS, PPO_STEPS)
    lidar = {"sensing": ("lidar",)}
    mode = f", {NOT_MEASURED}" if quick else ""
    print(f"[bench.rl] steps/s, one run each, load {os.getloadavg()[0]:.1f} at the start{mode}")
    print(f"  {'id':<20} {'raw':>8} {'raw lidar':>10} {'PPO':>8} {'PPO lidar':>10}")
    for env_id in llmnav.gym.ENV_IDS:
        cells = [
            raw_rate(env_id, raw),
            raw_rate(env_id, raw, **lidar),
            ppo_rate(env_id, ppo),
            ppo_rate(env_id, ppo, **lidar),
        ]
        widths = (8, 10, 8, 10)
        print(f"  {env_id.split('/')[1]:<20} " + " ".join(f"{c:>{w}.0f}" for c, w in zip(cells, widths, strict=True)))
    print(f"  load {os.getloadavg()[0]:.1f} at the end")


if __name__ == "__main__":
    main(quick=quick_from_env())
