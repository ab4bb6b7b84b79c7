"""What an LLM planner reads per decision: the compact LiDAR line, and the per-call token counts."""

from __future__ import annotations

import math

import numpy as np

from llmnav.backends.base import ChatResult
from llmnav.planners.observe import compact_lidar_line, new_prompt_tokens
from llmnav.scoring.metrics import new_prompt_tokens_median
from llmnav.sensing.perception import summarize_scan
from llmnav.sim.sensors import LidarScan


def _scan() -> LidarScan:
    angles = np.radians(np.arange(-180.0, 180.0, 1.0))
    ranges = np.full(angles.shape, np.inf)
    ranges[np.argmin(np.abs(angles - math.radians(40)))] = 2.345  # left front
    ranges[np.argmin(np.abs(angles - math.radians(-20)))] = 0.87  # right front
    ranges[np.abs(angles) <= math.radians(3)] = 4.06  # straight ahead
    return LidarScan(angles, ranges)


def test_lidar_line_carries_every_sector_rounded_and_nothing_static() -> None:
    line = compact_lidar_line(summarize_scan(_scan(), sectors=8, fov_deg=90.0))
    head, _, cells = line.partition(": ")
    assert head == "LiDAR front 4.1 m; closest m@deg per sector, left to right"
    entries = cells.split(" ")
    assert len(entries) == 8
    # Left to right over 90 deg in 11.25 deg sectors: the +40 deg reading in the first, straight ahead
    # (+-3 deg) split between the fourth and fifth (0 deg belongs to the right one, ties go to the first
    # ray in scan order), -20 deg in the sixth; nothing in range says inf. 0.1 m and whole degrees.
    assert entries == ["2.3@+40", "inf", "inf", "4.1@+1", "4.1@-3", "0.9@-20", "inf", "inf"]
    assert "deg:" not in line and "to" not in cells  # the sector spans live in the system prompt


def test_new_prompt_tokens_from_the_reply() -> None:
    direct = ChatResult("x", 0.1, "m", prompt_tokens=300, meta={"new_prompt_tokens": 18, "cached_tokens": 282})
    assert new_prompt_tokens(direct) == 18
    derived = ChatResult("x", 0.1, "m", prompt_tokens=300, meta={"cached_tokens": 250})
    assert new_prompt_tokens(derived) == 50
    assert new_prompt_tokens(ChatResult("x", 0.1, "m", prompt_tokens=120)) == 120  # no cache information
    assert new_prompt_tokens(ChatResult("x", 0.1, "m")) is None


def test_median_skips_the_first_call() -> None:
    calls = [{"new_prompt_tokens": 900}, {"new_prompt_tokens": 20}, {"new_prompt_tokens": 30}, {"error": "x"}]
    assert new_prompt_tokens_median(calls) == 25.0
    assert new_prompt_tokens_median(calls[:1]) is None
