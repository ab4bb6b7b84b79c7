"""The baselines under `sensed` information: their pose is odometry corrected by scan matching, not the truth.

In a factory whose odometry drifts far more than its own (wheel radii 1 %, track width 3 %), the oracle and
frontier baselines still reach their targets, the pose they believe stays within the issue's bound at every
scan, and the summary reports it; the raw odometry at the end is well past that bound (the test fails if the
baselines went back to reading the true pose: no estimate is then logged, or to believing odometry alone).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
import yaml

from llmnav.baselines.frontier import FrontierPlanner
from llmnav.baselines.oracle import OraclePlanner
from llmnav.planners.base import EpisodeContext, EpisodeOutcome, Planner, drive_options
from llmnav.runs.runner import EpisodeSpec, run_episode
from llmnav.world.scenario import OdometryConfig, resolve_scenario_path

DRIFTING = OdometryConfig(wheel_scale_std=0.01, track_scale_std=0.03, wheel_noise_m_per_sqrt_m=0.01)
BOUND_M = 0.10  # [m] the ceiling on the median final error, here held at every scan


def _drifting_factory(tmp_path: Path) -> Path:
    data = yaml.safe_load(resolve_scenario_path("factory").read_text())
    data["sensors"]["odometry"] = DRIFTING.model_dump()
    path = tmp_path / "drifting_factory.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def _with_odometry_error(base: type[Planner[Any]], errors: list[float]) -> Planner[Any]:
    """The baseline, noting how far raw odometry ended from the truth (the test's yardstick, not its input)."""

    class Noting(base):  # type: ignore[valid-type,misc]
        def run(self, ctx: EpisodeContext[Any]) -> EpisodeOutcome:
            outcome = super().run(ctx)
            odom, truth = ctx.world.robot.odom(), ctx.world.robot.pose()
            errors.append(truth.distance_to(odom.x, odom.y))
            return outcome

    return Noting()


@pytest.mark.parametrize("base", [OraclePlanner, FrontierPlanner], ids=["oracle", "frontier"])
def test_a_sensed_baseline_keeps_its_pose_error_bounded_under_drifting_odometry(
    base: type[Planner[Any]], tmp_path: Path
) -> None:
    scenario = _drifting_factory(tmp_path)
    odometry_errors: list[float] = []
    out = tmp_path / "run"
    spec = EpisodeSpec(
        scenario=str(scenario),
        task_id="T1",
        start_pose=2,
        options=drive_options(planner=base.name, information="sensed"),
        out_dir=out,
        plots=False,
    )
    summary = run_episode(spec, planner_obj=_with_odometry_error(base, odometry_errors))
    assert summary["information"] == "sensed"
    assert summary["success"] and summary["collisions"] == 0, summary["reason"]
    events = [json.loads(line) for line in (out / "run.jsonl").read_text().splitlines()[1:]]
    matched = [e for e in events if e["type"] == "localize" and e.get("accepted")]
    assert len(matched) >= 3  # the belief is corrected by scans on the way, not once
    assert summary["pose_error_m"]["max"] <= BOUND_M
    assert odometry_errors[0] > 2 * BOUND_M  # what believing odometry alone would have left


def test_with_oracle_information_the_baselines_log_no_estimate(tmp_path: Path) -> None:
    spec = EpisodeSpec(
        scenario="factory", task_id="T3", start_pose=3, options=drive_options(planner="oracle"), out_dir=tmp_path,
        plots=False,
    )  # fmt: skip
    summary = run_episode(spec)
    assert summary["information"] == "oracle" and summary["success"]
    assert summary["pose_error_m"] is None  # the true pose: nothing estimated, nothing to score
