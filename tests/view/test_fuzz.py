"""Any JSON in any field of any event: the page (and the model behind it) is built, never a traceback."""

from __future__ import annotations

import json
from pathlib import Path

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from llmnav.view.model import build_run_view
from llmnav.view.page import run_page

FIELDS = [
    "step", "pose", "pose_before", "pose_after", "image", "lidar_text", "lidar_front_m", "detections", "purpose",
    "request", "reply", "error", "outcome", "attempt", "command", "parameters", "kind", "points", "valid",
    "problems", "obstacle", "verdict", "t_sim", "t_recv", "base", "raw", "fused", "state", "option", "collided",
]  # fmt: skip
TYPES = ["observation", "llm_call", "guard", "action", "planner", "pose", "end"]

json_values = st.recursive(
    st.none() | st.booleans() | st.integers(-5, 5) | st.floats(allow_nan=False, width=32) | st.text(max_size=8),
    lambda inner: (
        st.lists(inner, max_size=4) | st.dictionaries(st.sampled_from(FIELDS + ["text", "messages"]), inner, max_size=4)
    ),
    max_leaves=12,
)
KINDS = ["cmd", "suggestion", "fsm_state", "waypoint_attempt", "replan", "grounding", "oracle_path"]
events = st.lists(
    st.builds(
        lambda kind, planner_kind, fields: {"type": kind, "kind": planner_kind, **fields},
        st.sampled_from(TYPES),
        st.sampled_from(KINDS),
        st.dictionaries(st.sampled_from([f for f in FIELDS if f != "kind"]), json_values, max_size=6),
    ),
    max_size=12,
)


configs = st.dictionaries(st.sampled_from(["task", "options", "start_pose", "backend", "information"]), json_values)


PLANNERS = ["stepwise", "hybrid", "fsm", "waypoints", "oracle", "not-installed"]  # the last: read from its log


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(events=events, planner=st.sampled_from(PLANNERS), extra=configs)
def test_any_event_fields_give_a_page(tmp_path_factory, events, planner, extra):
    run = Path(tmp_path_factory.mktemp("fuzz"))
    config = {"type": "config", "scenario": "nowhere", "planner": planner, "task": {"text": "Go"}, **extra}
    (run / "run.jsonl").write_text("\n".join(json.dumps(e) for e in [config, *events]) + "\n", encoding="utf-8")
    view = build_run_view(run)
    page = run_page(run)
    assert page.count('<section class="step" ') == len(view.steps)
