"""Benchmark of the embedded `local` backend (SmolLM2-135M via xllamacpp) against docs/sources.md (M).

Measures cold load, the first (cold-cache) stepwise decision, warm decisions (system prompt served from
the KV cache), decode speed and the process's peak RSS, and prints them beside the targets.
"""

from __future__ import annotations

import json
import os
import resource
import statistics
import sys
import time

from llmnav.backends.base import ChatRequest, ChatResult, Message
from llmnav.backends.local import LocalBackend

REPEATS = 5  # warm decisions measured
# llama.cpp threads: docs/sources.md (M) was measured with 2; on a busy 2-core box 1 is far faster (local.py).
THREADS = int(os.environ.get("LLMNAV_LOCAL_THREADS", "2"))
MAX_TOKENS = 160  # [tokens] budget of one stepwise answer

# A stepwise system prompt of realistic size (~600 tokens): role, commands, constraints, sensors, format.
SYSTEM_PROMPT = """You are the autonomous controller of a wheeled robot working in a factory hall.
Each turn you receive the user's task (on the first turn), a summary of the laser scanner and the
result of your previous action. You answer with exactly one JSON object and nothing else.

Commands you can give, one per answer:
- FRONT: drive straight forward; parameters is the distance in metres.
- BACK: drive straight backward; parameters is the distance in metres.
- ROTATE_LEFT: turn in place counter-clockwise; parameters is the angle in degrees.
- ROTATE_RIGHT: turn in place clockwise; parameters is the angle in degrees.
- COMPLETE: the task is done; parameters is 0.

Movement rules:
- Prefer moves of at least 1.0 metre and turns of at least 15 degrees, unless a precise final
  approach needs smaller steps.
- Never drive into an obstacle: check the front distance before every FRONT and keep half a metre
  of clearance. If the front is blocked, rotate towards the most open sector first.
- When you reach the target, stop between 1.5 and 2.5 metres from it, facing it, then send COMPLETE.

How to work, every turn:
1. Read the task and remember it; it does not change.
2. Read the laser summary. The front distance is the free range straight ahead. Each sector line gives
   the closest distance inside its angular range and the bearing where it occurs; bearings are
   positive to the left. Small values mean an obstacle; large values or inf mean open space.
3. Compare with what you saw before: did the last action bring you closer? Are you turning in circles?
4. Choose the single action that makes the most progress safely. If you have no idea where the target
   is, explore: rotate in steps of 45 degrees to look around, then drive towards open space.
5. Write the answer.

Laser guidelines:
- The scanner sees 360 degrees up to 10 metres. Its summary has 8 sectors over the front 90 degrees.
- A front distance below 1.0 metre means you must not drive forward.
- Narrow gaps narrower than the robot (0.7 metres) are not passable even if the far range is large.

Output format: one JSON object with these keys.
- goal: the target you are looking for, in a few words.
- reasoning: one or two short sentences on why you chose the action.
- scene_description: what the sensors tell you about the surroundings, briefly.
- action: an object with command (one of the five commands) and parameters (a number).

Example answer:
{"goal": "pile of pellets", "reasoning": "The front is open for 6 m and the target should be ahead.",
 "scene_description": "Open floor ahead, shelves on the right at 1.2 m.",
 "action": {"command": "FRONT", "parameters": 2.0}}

Priorities, in order: avoid collisions; use the laser summary; be accurate rather than fast; stay
consistent with your earlier answers; explore when the target has not been seen yet; finish with
COMPLETE only when the target is close and in front of you.
"""

STEP_SCHEMA = {
    "type": "object",
    "properties": {
        "goal": {"type": "string", "maxLength": 60},
        "reasoning": {"type": "string", "maxLength": 120},
        "scene_description": {"type": "string", "maxLength": 100},
        "action": {
            "type": "object",
            "properties": {
                "command": {"enum": ["FRONT", "BACK", "ROTATE_LEFT", "ROTATE_RIGHT", "COMPLETE"]},
                "parameters": {"type": "number"},
            },
            "required": ["command", "parameters"],
        },
    },
    "required": ["goal", "reasoning", "scene_description", "action"],
}

# Targets: the measured speeds in docs/sources.md (M), xllamacpp on these machines.
TARGET_LOAD = (0.9, 1.1)  # [s]
TARGET_WARM = (1.6, 2.3)  # [s]
TARGET_DECODE = (35.0, 40.0)  # [tok/s] generation under grammar
TARGET_PROMPT = 130.0  # [tok/s] prompt evaluation
TARGET_RSS = 268.0  # [MB]


def _user_turn(step: int) -> str:
    front = 4.0 - 0.4 * step
    sectors = "; ".join(
        f"sector {i}: {1.5 + 0.3 * ((i + step) % 5):.1f} m at {-45 + 11.25 * i:+.0f} deg" for i in range(8)
    )
    return f"Task: go to the pile of pellets. Step {step + 1}. Front distance {front:.1f} m. {sectors}."


def _request(step: int) -> ChatRequest:
    messages = (Message("system", SYSTEM_PROMPT), Message("user", _user_turn(step)))
    return ChatRequest(messages=messages, json_schema=STEP_SCHEMA, max_tokens=MAX_TOKENS, seed=step)


def _decision(backend: LocalBackend, step: int) -> ChatResult:
    result = backend.chat(_request(step))
    json.loads(result.text)  # a decision is only a decision if it parses
    return result


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # Linux reports KiB


def _row(name: str, value: str, target: str, ratio: float | None) -> str:
    shown = f"{ratio:.2f}x" if ratio is not None else ""
    return f"  {name:<34} {value:>12}   {target:<14} {shown}"


def main() -> None:
    """Print the benchmark table."""
    backend = LocalBackend(threads=THREADS)
    started = time.perf_counter()
    backend.load()
    load_s = time.perf_counter() - started

    cold = _decision(backend, 0)
    warm = [_decision(backend, step) for step in range(1, REPEATS + 1)]
    warm_s = statistics.median(r.latency_s for r in warm)
    decode = statistics.median(r.meta["tokens_per_s"] for r in warm if r.meta.get("tokens_per_s"))
    prompt_speed = cold.prompt_tokens / (cold.meta["prompt_ms"] / 1000) if cold.meta.get("prompt_ms") else 0.0
    cached = statistics.median(r.meta["cached_tokens"] for r in warm)
    answer_tokens = statistics.median(r.completion_tokens or 0 for r in warm)
    rss = _peak_rss_mb()
    load_avg = os.getloadavg()[0]  # other processes on the box skew every number; shown for context

    print(f"[bench.local] {backend.load().model_name}, {THREADS} threads, load avg {load_avg:.1f}")
    print(
        f"  prompt {cold.prompt_tokens} tokens ({cached:.0f} cached warm), answers ~{answer_tokens:.0f} tok"
    )
    print(
        _row("cold load [s]", f"{load_s:.2f}", f"{TARGET_LOAD[0]}-{TARGET_LOAD[1]}", load_s / TARGET_LOAD[1])
    )
    print(_row("cold first decision [s]", f"{cold.latency_s:.2f}", "", None))
    print(
        _row(
            f"warm decision, median of {REPEATS} [s]",
            f"{warm_s:.2f}",
            f"{TARGET_WARM[0]}-{TARGET_WARM[1]}",
            warm_s / TARGET_WARM[1],
        )
    )
    print(
        _row(
            "prompt evaluation [tok/s]",
            f"{prompt_speed:.0f}",
            f"{TARGET_PROMPT:.0f}",
            prompt_speed / TARGET_PROMPT,
        )
    )
    print(
        _row(
            "generation under grammar [tok/s]",
            f"{decode:.1f}",
            f"{TARGET_DECODE[0]:.0f}-{TARGET_DECODE[1]:.0f}",
            decode / TARGET_DECODE[0],
        )
    )
    print(_row("peak RSS [MB]", f"{rss:.0f}", f"~{TARGET_RSS:.0f}", rss / TARGET_RSS))
    print(f"  warm speed-up from the cached system prompt: {cold.latency_s / warm_s:.1f}x")
    sys.stdout.flush()


if __name__ == "__main__":
    main()
