"""The FSM assist's acceptance rules (source C): parse, freshness (TTL), bounds, projection, rate limits."""

from __future__ import annotations

import pytest

from llmnav.planners.fsm import FsmConfig, check_suggestion, project, rate_limit

CFG = FsmConfig()


def test_accepts_fresh_well_formed_in_bounds():
    verdict, value, _ = check_suggestion('{"linear_x": 0.05, "angular_z": -0.2}', 1.0, 1.2, 0.5, CFG)
    assert verdict == "accepted" and value == (0.05, -0.2)


@pytest.mark.parametrize(
    "text",
    ["not json", '{"linear_x": 0.05}', '{"linear_x": "fast", "angular_z": 0}', '{"linear_x": NaN, "angular_z": 0}'],
)
def test_malformed_is_parse(text):
    assert check_suggestion(text, 1.0, 1.1, 0.5, CFG)[0] == "parse"


def test_stale_after_ttl():
    verdict, value, detail = check_suggestion('{"linear_x": 0.05, "angular_z": 0.0}', 1.0, 1.51, 0.5, CFG)
    assert verdict == "stale" and value is None and "TTL" in detail


def test_out_of_bounds():
    assert check_suggestion('{"linear_x": 0.5, "angular_z": 0.0}', 1.0, 1.1, 0.5, CFG)[0] == "bounds"
    assert check_suggestion('{"linear_x": 0.01, "angular_z": 9.0}', 1.0, 1.1, 0.5, CFG)[0] == "bounds"
    assert check_suggestion('{"linear_x": 1e308, "angular_z": 0}', 1.0, 1.1, 0.5, CFG)[0] == "bounds"


def test_failed_call_is_error():
    assert check_suggestion(None, 1.0, 1.1, 0.5, CFG)[0] == "error"


def test_projection_clips_reverse_speed_to_v_min():
    assert project(-0.05, 0.1, CFG) == (CFG.v_min, 0.1)


def test_rate_limit_is_first_order():
    assert rate_limit(1.0, 0.0, 0.1, 0.02) == pytest.approx(0.002)
    assert rate_limit(0.001, 0.0, 0.1, 0.02) == pytest.approx(0.001)
    assert rate_limit(-1.0, 0.0, 2.0, 0.02) == pytest.approx(-0.04)
