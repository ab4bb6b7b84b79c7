"""Finite-state machine with asynchronous LLM assist (source C: sign-following in a maze).

A deterministic 50 Hz FSM (SEARCH, APPROACH, ACT_LEFT, ACT_RIGHT, ACT_STOP) drives toward traffic signs
seen by the detector. Its baseline command is v = sat(k_v (d - d_goal)), w = sat(k_w e_theta) with
first-order rate limits. With `--assist llm` a model proposes a velocity from a state message published
only in APPROACH; a proposal is used only if well-formed and inside the admissible box (the guard judges
both), and fresh (t_recv - t_stamp <= TTL), then fused, v = (1 - alpha) v_base + alpha v_llm, and held
until a newer one arrives or it expires. With `--assist ema` the baseline is smoothed instead:
v_t = (1 - beta) v_{t-1} + beta v_base. A schema the backend cannot compile is reported before the first tick.

Model latency charged to simulation time (`--model-latency`): what the backend reports for the call
(`measured`, the default: the wall time of a live call, the original run's in a replay), the replay's
recorded latency (`recorded`, a replay backend only), or a fixed number of milliseconds (reproduces,
say, a Jetson's timing on a laptop). `--ttl auto` adapts the TTL to the latencies seen.

The loop never waits for the model. Two timing modes:
- virtual (default): simulation time is the only clock. The model is called between ticks while the
  simulation is frozen, and its measured latency is charged to simulation time before the answer can be
  used, so the run is deterministic for a deterministic backend (replay returns the recorded latency).
- realtime (`--realtime`): ticks are paced to the wall clock and the model runs in a worker thread, or,
  when it computes inside this process (the local backend), in a process of its own that the loop
  thread polls between ticks, so the loop never waits for the GIL (llmnav.backends.isolated); answers
  are used at the tick after they arrive.
Tick latency is the controller's own work (tick start -> command published): the answer in force, the
state machine, the baseline and the fusion. Physics stepping, the detector (a separate perception node at
`perception_hz`) and reading and judging the model's answer (the assist's node) are not the controller.

Modules: `control` (the pure tick and its constants), `assist` (state line, the guard's judgment, TTL and
hold), `workers` (the model's thread or process under `--realtime`), `stats` (counters and metrics),
`options` (its own options model, `FsmOptions`), `tables` (its score table and view declarations),
`planner` (the loop).
The oracle's answers live one layer below, in `llmnav.planners.fsm.oracle`.
"""

from llmnav.planners.fsm.assist import (
    TTL_AUTO_MAX_MS,
    TTL_AUTO_MIN_MS,
    adaptive_ttl_ms,
    check_suggestion,
    state_message,
)
from llmnav.planners.fsm.control import FsmConfig, rate_limit, tick
from llmnav.planners.fsm.options import FsmOptions
from llmnav.planners.fsm.planner import FsmPlanner

__all__ = [
    "TTL_AUTO_MAX_MS",
    "TTL_AUTO_MIN_MS",
    "FsmConfig",
    "FsmOptions",
    "FsmPlanner",
    "adaptive_ttl_ms",
    "check_suggestion",
    "rate_limit",
    "state_message",
    "tick",
]
