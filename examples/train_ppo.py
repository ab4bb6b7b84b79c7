"""PPO (Stable-Baselines3) on an llmnav environment: train, save, then drive one episode with the policy.

    pip install 'llmnav[rl]'                                  # SB3 with the CPU torch pin
    python examples/train_ppo.py                              # Corridor, 4096 steps, LiDAR only
    python examples/train_ppo.py --env llmnav/Maze-v0 --sensing lidar,image --timesteps 2048

`llmnav.gym.make_sb3` gives the environment array-only spaces (no task text; Factory's action as a
`Discrete` table; velocities in [-1, 1]); the safety veto stays between the policy and the robot.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import llmnav.gym
from llmnav.errors import LlmnavError

SENSES = ("lidar", "image", "detections")


def main(argv: list[str] | None = None) -> int:
    """Train, save and try a PPO policy; returns the process exit code."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="llmnav/Corridor-v0", choices=llmnav.gym.ENV_IDS)
    parser.add_argument("--timesteps", type=int, default=4096)
    parser.add_argument("--n-steps", type=int, default=512, help="PPO rollout length per update")
    parser.add_argument("--sensing", default="lidar", help="comma-separated: lidar, image, detections")
    parser.add_argument("--max-steps", type=int, default=None, help="episode length (default: the env's)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("runs/ppo/policy.zip"))
    args = parser.parse_args(argv)
    sensing = tuple(s.strip() for s in args.sensing.split(",") if s.strip())
    if not sensing or set(sensing) - set(SENSES):
        print(f"error: --sensing takes {', '.join(SENSES)} (comma-separated), not {args.sensing!r}", file=sys.stderr)
        return 2
    if args.timesteps < 1 or args.n_steps < 2:
        print("error: --timesteps must be at least 1 and --n-steps at least 2", file=sys.stderr)
        return 2
    try:
        from stable_baselines3 import PPO
    except ImportError:
        print("error: this example needs Stable-Baselines3: pip install 'llmnav[rl]'", file=sys.stderr)
        return 2

    options: dict[str, Any] = {"sensing": sensing}
    if args.max_steps is not None:
        options["max_steps"] = args.max_steps
    try:
        env = llmnav.gym.make_sb3(args.env, **options)
    except (LlmnavError, ValueError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    try:
        batch = min(64, args.n_steps)
        model = PPO("MultiInputPolicy", env, n_steps=args.n_steps, batch_size=batch, seed=args.seed, device="cpu")
        started = time.perf_counter()
        model.learn(total_timesteps=args.timesteps)
        elapsed = time.perf_counter() - started
        print(f"trained {model.num_timesteps} steps in {elapsed:.1f} s ({model.num_timesteps / elapsed:.0f} steps/s)",
              file=sys.stderr)  # fmt: skip
        args.out.parent.mkdir(parents=True, exist_ok=True)
        model.save(args.out)
        obs, info = env.reset(seed=args.seed)
        total, done = 0.0, False
        while not done:
            action, _ = model.predict(obs, deterministic=True)
            obs, reward, terminated, truncated, info = env.step(action)
            total += float(reward)
            done = terminated or truncated
        print(
            f"policy saved to {args.out}; one episode: return {total:.3f}, score {info['score']:.3f}, "
            f"steps {info['steps']}, success {info['success']}, vetoes {info.get('vetoes', 0)}"
        )
    finally:
        env.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
