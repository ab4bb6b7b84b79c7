"""Environment throughput: steps/s of each Gymnasium id, raw (random actions) and under SB3's PPO.

`python -m bench rl` (needs the `rl` extra). "raw" steps the `gymnasium.make` environment (safety veto on)
with sampled actions; "raw, LiDAR only" drops the camera and detections; "PPO" is `make_sb3` under
`PPO("MultiInputPolicy")`, rollouts and updates included, one torch thread (the simulation has the other
core), with the env's default sensing and with LiDAR only. One run each; wall time on a shared machine,
so the load average is printed with the table. Quick mode: 20 raw steps and one PPO update of 32 steps.
"""

from __future__ import annotations

import os
import time
from typing import Any

import gymnasium as gym

import llmnav.gym
from bench import NOT_MEASURED, quick_from_env

RAW_STEPS = 300
PPO_STEPS = 512  # two PPO updates of 256 steps
QUICK_RAW_STEPS = 20
QUICK_PPO_STEPS = 32  # one update of 32 steps


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
