"""An llmnav backend as a Gymnasium agent: text observation in, guarded action out, scored by `llmnav score`.

    python examples/gym_llm_agent.py                                  # embedded local model, factory T6
    python examples/gym_llm_agent.py --backend openai:qwen2.5@http://127.0.0.1:8080/v1 --task-id T1
    llmnav score runs/gym-agent

The environment (`llmnav/Factory-v0`, safety-vetoed) gives the observation as the text llmnav's stepwise
planner sends (`TextObservation`); the model answers the stepwise JSON under its schema; the guard
(`ask_guarded`: extract, repair, schema, bounds) turns the answer into an action or a correction turn; `RunLog` writes
the run folders. Whatever the model says, it reaches the robot only through the guard and the veto.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np

import llmnav.gym
from llmnav.backends.base import get_backend
from llmnav.core.chat import ChatRequest, Message
from llmnav.errors import LlmnavError
from llmnav.guard.ask import CallContext, ask_guarded
from llmnav.guard.schemas import response_schema
from llmnav.planners import prompting
from llmnav.planners.stepwise.answers import ActionBounds, StepAction

MAX_CORRECTIONS = 2  # guard correction turns per step


def to_action(answer: StepAction) -> dict[str, object]:
    """The guarded answer as the environment's action (units as the stepwise source: m, deg)."""
    command = answer.action.command.value
    value = float(answer.action.parameters)
    is_move = command in ("FRONT", "BACK")
    return {
        "command": llmnav.gym.FactoryEnv.COMMANDS.index(command),
        "distance_m": np.array([value if is_move else 0.0], dtype=np.float32),
        "angle_deg": np.array([0.0 if is_move else value], dtype=np.float32),
    }


def main(argv: list[str] | None = None) -> int:
    """Run episodes of the factory with a model as the agent; returns the process exit code."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--backend", default="local")
    parser.add_argument("--task-id", default="T6")
    parser.add_argument("--start-pose", type=int, default=1)
    parser.add_argument("--max-steps", type=int, default=6)
    parser.add_argument("--episodes", type=int, default=1)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("runs/gym-agent"))
    args = parser.parse_args(argv)

    try:
        backend = get_backend(args.backend)
    except LlmnavError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    env = gym.make(
        "llmnav/Factory-v0", task_id=args.task_id, start_pose=args.start_pose, max_steps=args.max_steps
    )
    env = llmnav.gym.RunLog(llmnav.gym.TextObservation(env), args.out, agent="llm", backend=backend.spec)
    bounds = ActionBounds()
    system = Message(
        "system",
        prompting.render(
            "short",
            max_step_m=bounds.max_step_m,
            lidar=True,
            image=False,
            detections=True,
            lidar_sectors=8,
            lidar_fov_deg=90.0,
        ),
    )
    schema = response_schema(StepAction)
    guard_ctx = CallContext(lambda request, purpose: backend.chat(request))
    try:
        for episode in range(args.episodes):
            text, info = env.reset(seed=args.seed + episode)
            done = False
            while not done:
                request = ChatRequest(
                    messages=(system, Message("user", str(text))), json_schema=schema, max_tokens=256
                )
                answer = ask_guarded(guard_ctx, request, StepAction, bounds, MAX_CORRECTIONS).value
                if answer is None:  # RunLog closes the episode as aborted at the next reset or close
                    print(f"no valid answer after {MAX_CORRECTIONS} corrections: episode aborted", file=sys.stderr)
                    break
                text, reward, terminated, truncated, info = env.step(to_action(answer))
                print(f"step {info['steps']}: {answer.action.command.value} {answer.action.parameters:g} "
                      f"reward {float(reward):+.3f}{'  VETOED' if info.get('vetoed') else ''}", file=sys.stderr)
                done = terminated or truncated
            print(f"episode {episode + 1}: score {info['score']:.2f}, success {info['success']}", file=sys.stderr)
    except LlmnavError as err:
        print(f"error: {err}", file=sys.stderr)
        return 1
    finally:
        env.close()
        backend.close()
    print(f"run folders under {args.out}; score them with: llmnav score {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
