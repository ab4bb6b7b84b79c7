"""The FSM assist's acceptance rules (source C): parse, freshness (TTL), bounds (the guard's), rate limits."""

from __future__ import annotations

import pytest

from llmnav.planners.fsm import FsmConfig, check_suggestion, rate_limit

CFG = FsmConfig()


def test_accepts_fresh_well_formed_in_bounds():
    verdict, value, _ = check_suggestion("[50,-200]", 1.0, 1.2, 0.5, CFG)
    assert verdict == "accepted" and value == (0.05, -0.2)  # mm/s and mrad/s -> m/s and rad/s


@pytest.mark.parametrize(
    "text",
    ["not json", "[50]", '["fast", 0]', "[NaN, 0]", "[0.5, 0]", "[1, 2, 3]", '{"v": 50, "w": 0}'],
)
def test_malformed_is_parse(text):
    assert check_suggestion(text, 1.0, 1.1, 0.5, CFG)[0] == "parse"


def test_stale_after_ttl():
    verdict, value, detail = check_suggestion("[50,0]", 1.0, 1.51, 0.5, CFG)
    assert verdict == "stale" and value is None and "TTL" in detail


def test_out_of_bounds():
    assert check_suggestion("[500,0]", 1.0, 1.1, 0.5, CFG)[0] == "bounds"
    assert check_suggestion("[10,9000]", 1.0, 1.1, 0.5, CFG)[0] == "bounds"
    assert check_suggestion("[61,0]", 1.0, 1.1, 0.5, CFG)[0] == "bounds"  # just past v_max = 60 mm/s
    assert check_suggestion("[60,-800]", 1.0, 1.1, 0.5, CFG)[0] == "accepted"  # the box's corner


def test_failed_call_is_error():
    assert check_suggestion(None, 1.0, 1.1, 0.5, CFG)[0] == "error"


def test_reverse_speed_is_outside_the_box_the_schema_states():
    # The box is [v_min, v_max] x [-w_max, w_max], as the answer's schema says: a backend without the
    # grammar that sends a reverse speed is rejected for bounds (no projection makes it another command).
    verdict, value, detail = check_suggestion("[-50,100]", 1.0, 1.1, 0.5, CFG)
    assert verdict == "bounds" and value is None and "0 <= v <= 60" in detail


def test_parse_comes_before_freshness_and_freshness_before_bounds():
    assert check_suggestion("[50]", 1.0, 9.0, 0.5, CFG)[0] == "parse"  # stale too
    assert check_suggestion("[500,0]", 1.0, 9.0, 0.5, CFG)[0] == "stale"  # out of the box too


def test_the_guard_judges_with_the_box_and_logs_its_verdict():
    from llmnav.planners.fsm.assist import answer_box, judge

    judged = judge("[500,0]", answer_box(CFG))
    assert judged.value is None and judged.outcome == "bounds"
    ((kind, fields),) = judged.events
    assert kind == "guard" and fields["outcome"] == "bounds" and fields["purpose"] == "suggestion"
    assert judge("[60,-800]", answer_box(CFG)).events[0][1]["outcome"] == "ok"


def test_rate_limit_is_first_order():
    assert rate_limit(1.0, 0.0, 0.1, 0.02) == pytest.approx(0.002)
    assert rate_limit(0.001, 0.0, 0.1, 0.02) == pytest.approx(0.001)
    assert rate_limit(-1.0, 0.0, 2.0, 0.02) == pytest.approx(-0.04)


# --- the compact state line, --model-latency / --ttl parsing, the adaptive TTL --------------------


def test_state_line_is_class_distance_offset_and_baseline_in_milli_units():
    from llmnav.planners.fsm import state_message

    assert state_message("stop", 1.23456, -0.1049, 0.0451, -0.15) == "stop 1.23 -0.10 45 -150"
    assert state_message(None, 0.8, 0.5, 0.0, 0.0) == "none 0.80 +0.50 0 0"


@pytest.mark.parametrize(
    ("given", "expected"),
    [
        ({"model_latency": "measured"}, {"model_latency": "measured"}),
        ({"model_latency": "186", "ttl": "auto"}, {"model_latency": 186.0, "ttl_auto": True}),
        ({"ttl": "250"}, {"ttl_ms": 250.0, "ttl_auto": False}),
        ({"model_latency": "0"}, {"model_latency": 0.0}),
        ({"model_latency": " Recorded "}, {"model_latency": "recorded"}),
    ],
)
def test_timing_options_parse(given, expected):
    from llmnav.planners.base import planner_options

    options, ignored = planner_options("fsm", given)
    assert ignored == []
    assert {key: getattr(options, key) for key in expected} == expected


@pytest.mark.parametrize(
    ("latency", "ttl", "flag"),
    [
        ("-5", None, "--model-latency"),
        ("fast", None, "--model-latency"),
        ("nan", None, "--model-latency"),
        (None, "soon", "--ttl"),
        (None, "0", "--ttl"),
        (None, "-1", "--ttl"),
    ],
)
def test_timing_options_reject_bad_values(latency, ttl, flag, tmp_path):
    from typer.testing import CliRunner

    from llmnav.cli import app

    args = ["drive", "--planner", "fsm", "--task", "go to the stop sign", "--out", str(tmp_path / "run")]
    args += ["--model-latency", latency] if latency is not None else ["--ttl", ttl]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 2, result.output
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and flag in lines[0], result.output
    assert not (tmp_path / "run").exists()


def test_a_recorded_latency_needs_a_replay_backend(tmp_path):
    from typer.testing import CliRunner

    from llmnav.cli import app

    args = ["drive", "--planner", "fsm", "--assist", "llm", "--model-latency", "recorded", "--backend", "policy:first"]
    result = CliRunner().invoke(app, [*args, "--task", "go to the stop sign", "--out", str(tmp_path / "run")])
    assert result.exit_code == 2, result.output
    assert "--model-latency recorded needs a replay backend" in result.output
    assert not (tmp_path / "run").exists()


def test_adaptive_ttl_is_p95_times_factor_bounded():
    from llmnav.planners.fsm import TTL_AUTO_MAX_MS, TTL_AUTO_MIN_MS, adaptive_ttl_ms

    assert adaptive_ttl_ms([300.0] * 4) is None  # too few samples: keep the start TTL
    latencies = [100.0 + 10.0 * i for i in range(20)]  # 100 .. 290 ms
    p95 = 100.0 + 10.0 * 19 * 0.95  # numpy's linear interpolation over 20 evenly spaced values
    assert adaptive_ttl_ms(latencies) == pytest.approx(p95 * 1.2)
    assert adaptive_ttl_ms([10.0] * 10) == TTL_AUTO_MIN_MS
    assert adaptive_ttl_ms([9000.0] * 10) == TTL_AUTO_MAX_MS
