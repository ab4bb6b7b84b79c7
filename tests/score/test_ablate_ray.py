"""`--ray`: the same ablation as Ray tasks on a local Ray started by the test equals the serial run."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))
from score_fakes import fake_episode, write_scenario_file  # noqa: E402

from llmnav import ablate as lib  # noqa: E402
from llmnav.errors import BadInputError  # noqa: E402


def _grid(scenario_file: Path) -> lib.GridSpec:
    data = {"scenario": str(scenario_file), "tasks": ["T1"], "poses": [1, 2], "lidar_sectors": [3, 8]}
    return lib.grid_from_mapping(data, "test")


@pytest.mark.slow
def test_ray_equals_serial(tmp_path: Path) -> None:
    ray = pytest.importorskip("ray", reason="the optional extra llmnav[ray] is not installed")
    scenario_file = write_scenario_file(tmp_path / "tiny.yaml")
    grid = _grid(scenario_file)
    lib.run(lib.plan(grid, tmp_path / "serial"), runner=fake_episode)
    here = str(Path(__file__).parent)
    paths = os.pathsep.join([here, str(Path(__file__).parents[2]), os.environ.get("PYTHONPATH", "")])
    ray.init(num_cpus=2, include_dashboard=False, runtime_env={"env_vars": {"PYTHONPATH": paths}})
    try:
        lib.run(lib.plan(grid, tmp_path / "ray"), runner=fake_episode, ray_address="auto")
    finally:
        ray.shutdown()
    serial = json.loads((tmp_path / "serial" / "manifest.json").read_text())
    assert json.loads((tmp_path / "ray" / "manifest.json").read_text()) == serial
    assert serial["done"] == 4


def test_ray_missing_or_unreachable_is_one_line(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    scenario_file = write_scenario_file(tmp_path / "tiny.yaml")
    monkeypatch.setitem(sys.modules, "ray", None)  # as if the extra were not installed
    with pytest.raises(BadInputError, match=r"pip install 'llmnav\[ray\]'"):
        lib.run(lib.plan(_grid(scenario_file), tmp_path / "ab"), runner=fake_episode, ray_address="auto")
