"""PPO (Stable-Baselines3) to success on a corridor task: train, save, then evaluate over fresh episodes.

    pip install 'llmnav[rl]'                             # SB3 with the CPU torch pin, and moviepy
    python examples/train_ppo.py                         # train, save runs/ppo/policy.zip, evaluate 20 episodes
    python examples/train_ppo.py --timesteps 4096 --episodes 5

The task (`CORRIDOR_TASK`): `llmnav/Corridor-Flat-v0`, "Go to room 101" in corridor_a, each episode from a
random start (a free pose within 3 m of the listed start, any heading, drawn from the seed). The agent sees
its odometry and the goal as the corridor's published map places it (distance and bearing from the
odometry pose: the map and the odometry, never the true pose), chooses one of 15 (v, w) pairs, the stop
among them, each held for 0.25 s, and is rewarded by the metres it gains on the target plus 2 on success.
Success is llmnav's own: stopped within 0.5 m of room 101's goal point. The LiDAR is not in the
observation by default (`--sensing lidar` adds its 360 ranges, and PPO then needs many times the steps:
6 of 20 episodes after 28 672 steps in one run) but still feeds the safety veto, which stays between the
policy and the robot. `python -m bench rl` runs this example and reports its numbers.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path
from typing import Any

import llmnav.gym
from llmnav.errors import LlmnavError

ENV_ID = "llmnav/Corridor-Flat-v0"
CORRIDOR_TASK: dict[str, Any] = {
    "task_id": "A1",  # Go to room 101
    "sensing": (),  # odometry and the goal only (the veto still scans)
    "start": "random",
    "start_radius_m": 3.0,  # [m] around the listed start (0, 0)
    "reward": "progress",
    "success_bonus": 2.0,
    "velocity_actions": "discrete",
    "control_dt_s": 0.25,  # [s] a (v, w) is held this long: 0.1 m at full speed
    "max_steps": 100,  # 25 s of simulated time
}
TIMESTEPS = 8192  # [steps] of training (16 PPO updates of 512)
N_STEPS = 512  # [steps] per PPO update
EVAL_SEED = 10_000  # evaluation episode i starts from seed EVAL_SEED + i (training never draws these)
SENSES = ("lidar", "image", "detections")


def make_env(**overrides: Any) -> Any:
    """The corridor task's environment (`CORRIDOR_TASK` with `overrides`)."""
    return llmnav.gym.make_sb3(ENV_ID, **{**CORRIDOR_TASK, **overrides})


def train(env: Any, timesteps: int, *, n_steps: int = N_STEPS, seed: int = 0) -> tuple[Any, float]:
    """PPO with SB3's defaults but the rollout length and a small entropy bonus; (model, wall time [s])."""
    import torch
    from stable_baselines3 import PPO

    torch.set_num_threads(1)  # the simulation has the other core
    batch = min(64, n_steps)
    model = PPO("MlpPolicy", env, n_steps=n_steps, batch_size=batch, ent_coef=0.01, seed=seed, device="cpu")
    started = time.perf_counter()
    model.learn(total_timesteps=timesteps)
    return model, time.perf_counter() - started


def evaluate(model: Any, env: Any, episodes: int, *, first_seed: int = EVAL_SEED) -> list[dict[str, Any]]:
    """The final `info` of each of `episodes` episodes driven by the deterministic policy."""
    finals = []
    for i in range(episodes):
        obs, info = env.reset(seed=first_seed + i)
        done = False
        while not done:
            action, _ = model.predict(obs, deterministic=True)
            obs, _, terminated, truncated, info = env.step(action)
            done = terminated or truncated
        finals.append(info)
    return finals


def main(argv: list[str] | None = None) -> int:
    """Train, save and evaluate a PPO policy; returns the process exit code."""
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--timesteps", type=int, default=TIMESTEPS)
    parser.add_argument("--n-steps", type=int, default=N_STEPS, help="PPO rollout length per update")
    parser.add_argument("--episodes", type=int, default=20, help="evaluation episodes after training")
    parser.add_argument("--sensing", default="none", help="none, or comma-separated: lidar, image, detections")
    parser.add_argument("--max-steps", type=int, default=None, help="episode length (default: the task's)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("runs/ppo/policy.zip"))
    args = parser.parse_args(argv)
    sensing = tuple(s.strip() for s in args.sensing.split(",") if s.strip() and s.strip() != "none")
    if (not sensing and args.sensing.strip() != "none") or set(sensing) - set(SENSES):
        print(f"error: --sensing takes none or {', '.join(SENSES)} (comma-separated), not {args.sensing!r}",
              file=sys.stderr)  # fmt: skip
        return 2
    if args.timesteps < 1 or args.n_steps < 2 or args.episodes < 0:
        print("error: --timesteps must be at least 1, --n-steps at least 2, --episodes at least 0", file=sys.stderr)
        return 2
    try:
        import stable_baselines3  # noqa: F401
    except ImportError:
        print("error: this example needs Stable-Baselines3: pip install 'llmnav[rl]'", file=sys.stderr)
        return 2

    options: dict[str, Any] = {"sensing": sensing}
    if args.max_steps is not None:
        options["max_steps"] = args.max_steps
    try:
        env = make_env(**options)
    except (LlmnavError, ValueError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    try:
        load = os.getloadavg()[0]
        model, seconds = train(env, args.timesteps, n_steps=args.n_steps, seed=args.seed)
        steps = model.num_timesteps
        print(
            f"trained {steps} steps in {seconds:.0f} s ({steps / seconds:.0f} steps/s, load {load:.1f})",
            file=sys.stderr,
        )
        args.out.parent.mkdir(parents=True, exist_ok=True)
        model.save(args.out)
        finals = evaluate(model, env, args.episodes)
        wins = sum(bool(f["success"]) for f in finals)
        print(f"policy saved to {args.out}; success {wins}/{len(finals)} evaluation episodes")
    finally:
        env.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
