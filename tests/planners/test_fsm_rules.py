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
    ("latency", "ttl", "expected"),
    [
        ("measured", None, {"model_latency": "measured"}),
        ("186", "auto", {"model_latency": 186.0, "ttl_auto": True}),
        (None, "250", {"ttl_ms": 250.0}),
        ("0", None, {"model_latency": 0.0}),
    ],
)
def test_timing_options_parse(latency, ttl, expected):
    from llmnav.planners.fsm import timing_options

    assert timing_options(latency, ttl, "local") == expected


@pytest.mark.parametrize(
    ("latency", "ttl", "backend", "flag"),
    [
        ("-5", None, "local", "--model-latency"),
        ("fast", None, "local", "--model-latency"),
        ("nan", None, "local", "--model-latency"),
        ("recorded", None, "local", "--model-latency"),  # only a replay has a record
        (None, "soon", "local", "--ttl"),
        (None, "0", "local", "--ttl"),
        (None, "-1", "local", "--ttl"),
    ],
)
def test_timing_options_reject_bad_values(latency, ttl, backend, flag):
    from llmnav.errors import BadInputError
    from llmnav.planners.fsm import timing_options

    with pytest.raises(BadInputError, match=flag) as err:
        timing_options(latency, ttl, backend)
    assert err.value.exit_code == 2 and "\n" not in str(err.value)


def test_adaptive_ttl_is_p95_times_factor_bounded():
    from llmnav.planners.fsm import TTL_AUTO_MAX_MS, TTL_AUTO_MIN_MS, adaptive_ttl_ms

    assert adaptive_ttl_ms([300.0] * 4) is None  # too few samples: keep the start TTL
    latencies = [100.0 + 10.0 * i for i in range(20)]  # 100 .. 290 ms
    p95 = 100.0 + 10.0 * 19 * 0.95  # numpy's linear interpolation over 20 evenly spaced values
    assert adaptive_ttl_ms(latencies) == pytest.approx(p95 * 1.2)
    assert adaptive_ttl_ms([10.0] * 10) == TTL_AUTO_MIN_MS
    assert adaptive_ttl_ms([9000.0] * 10) == TTL_AUTO_MAX_MS
