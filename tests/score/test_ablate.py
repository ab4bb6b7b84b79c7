"""Ablation grids: expansion, seeds, manifest, interrupt + resume, parallel == serial, CLI errors."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

sys.path.insert(0, str(Path(__file__).parent))
from score_fakes import (  # noqa: E402
    CountingRunner,
    InterruptingRunner,
    fake_episode,
    served_episode,
    write_scenario_file,
)

from llmnav import ablate as lib  # noqa: E402
from llmnav.cli import app  # noqa: E402
from llmnav.errors import BadInputError  # noqa: E402


@pytest.fixture()
def scenario_file(tmp_path: Path) -> Path:
    return write_scenario_file(tmp_path / "tiny.yaml")


def _grid(scenario_file: Path, **extra: Any) -> lib.GridSpec:
    data = {
        "scenario": str(scenario_file),
        "tasks": ["T1", "T2"],
        "poses": [1],
        "trials": 2,
        "lidar_sectors": [3, 5, 8],
        "seed": 7,
    } | extra
    return lib.grid_from_mapping(data, "test")


def _manifest(root: Path) -> dict[str, Any]:
    return json.loads((root / "manifest.json").read_text())


def _without_layout(manifest: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in manifest.items() if k != "layout"}


def test_expand_keys_seeds_and_options(scenario_file: Path, tmp_path: Path) -> None:
    ab = lib.plan(_grid(scenario_file, sensing=["lidar+image", "image"]), tmp_path / "ab")
    assert ab.size == 2 * 1 * 2 * 3 * 2
    keys = [ep.key for ep in ab.episodes]
    assert len(set(keys)) == ab.size and len({ep.dir_name for ep in ab.episodes}) == ab.size
    first = ab.episodes[0]
    assert first.key == "T1-p1-t1-sensing=lidar+image-lidar_sectors=3"
    assert first.options.sensing == ("lidar", "image") and first.options.lidar_sectors == 3
    # every condition of one (task, pose, trial) shares its seed; trials differ
    same = {ep.seed for ep in ab.episodes if (ep.task_id, ep.trial) == ("T1", 1)}
    assert len(same) == 1
    assert first.seed == lib.episode_seed(7, "T1", 1, 1) != lib.episode_seed(7, "T1", 1, 2)
    assert lib.episode_seed(8, "T1", 1, 1) != first.seed
    assert first.options.seed == first.seed and first.backend == "local"
    # a factor with one value is not part of the key, but still sets the options
    grid = _grid(scenario_file, planner=["stepwise"], prompt=["short"], lidar_sectors=[5])
    single = lib.plan(grid, tmp_path / "s").episodes[0]
    assert single.key == "T1-p1-t1" and single.options.prompt == "short" and single.options.lidar_sectors == 5
    # all tasks, all poses
    assert lib.plan(lib.grid_from_mapping({"scenario": str(scenario_file)}, "t"), tmp_path).size == 5


def test_grid_errors_are_one_line(scenario_file: Path, tmp_path: Path) -> None:
    with pytest.raises(BadInputError, match="has 1 start pose"):
        lib.plan(_grid(scenario_file, poses=[1, 2]), tmp_path)
    with pytest.raises(BadInputError, match="no task 'T99'"):
        lib.plan(_grid(scenario_file, tasks=["T99"]), tmp_path)
    with pytest.raises(BadInputError, match="lidar_sectors"):  # option values: checked once the size is known
        lib.plan(_grid(scenario_file, lidar_sectors=["many"]), tmp_path)
    with pytest.raises(BadInputError, match="g.yaml: .*'colour' is no option of any planner"):
        lib.grid_from_mapping({"colour": 1}, "g.yaml")
    with pytest.raises(BadInputError, match="history"):
        lib.plan(_grid(scenario_file, history=["7"]), tmp_path)
    assert lib.parse_poses("1-3,5") == [1, 2, 3, 5] and lib.parse_poses("all") is None
    with pytest.raises(BadInputError):
        lib.parse_poses("a-b")
    bad = tmp_path / "bad.yaml"
    bad.write_text("lidar_sectors: [3, 5\n")
    with pytest.raises(BadInputError, match="bad.yaml: line"):
        lib.load_grid_file(bad)


def test_interrupt_and_resume_gives_the_same_manifest(scenario_file: Path, tmp_path: Path) -> None:
    grid = _grid(scenario_file)
    whole = lib.run(lib.plan(grid, tmp_path / "whole"), runner=fake_episode)
    assert all(e.status == "done" for e in whole.entries.values())

    killer = InterruptingRunner(kill_at=5)
    with pytest.raises(KeyboardInterrupt):
        lib.run(lib.plan(grid, tmp_path / "resumed"), runner=killer)
    partial = _manifest(tmp_path / "resumed")
    assert partial["done"] == 4 and partial["episodes"][4]["status"] == "pending"
    cut_dir = tmp_path / "resumed" / partial["episodes"][4]["dir"]
    assert (cut_dir / "run.jsonl").exists() and not (cut_dir / "summary.json").exists()

    counter = CountingRunner()
    lib.run(lib.plan(grid, tmp_path / "resumed"), runner=counter)
    assert len(counter.ran) == grid_size(grid) - 4  # finished episodes are skipped, the cut one redone
    cut = partial["episodes"][4]["dir"]
    assert cut + ".2" in counter.ran  # ... into a new folder: the cut one is kept, marked superseded
    assert (cut_dir / "run.jsonl").exists() and (cut_dir / "superseded.json").exists()
    resumed, whole = _manifest(tmp_path / "resumed"), _manifest(tmp_path / "whole")
    redone = resumed["episodes"][4]
    assert redone["dir"] == cut + ".2" and redone["kept"] == [f"{cut}: cut short (no summary)"]
    redone.update(dir=cut, summary=f"{cut}/summary.json", kept=[])
    assert resumed == whole
    # a third run has nothing left to do
    again = CountingRunner()
    lib.run(lib.plan(grid, tmp_path / "resumed"), runner=again)
    assert again.ran == []


def grid_size(grid: lib.GridSpec) -> int:
    return len(lib.expand(grid))


def test_another_grid_is_refused_and_other_conditions_get_new_folders(
    scenario_file: Path, tmp_path: Path
) -> None:
    grid = _grid(scenario_file, trials=1, lidar_sectors=[3])
    lib.run(lib.plan(grid, tmp_path / "ab"), runner=fake_episode)
    other = _grid(scenario_file, trials=1, lidar_sectors=[3], seed=99)
    counter = CountingRunner()
    with pytest.raises(BadInputError, match="seed: 7 there, 99 now"):
        lib.run(lib.plan(other, tmp_path / "ab"), runner=counter)
    assert counter.ran == []
    # without the manifest, the folder names are taken by runs of another condition: new folders
    (tmp_path / "ab" / "manifest.json").unlink()
    lib.run(lib.plan(other, tmp_path / "ab"), runner=counter)
    assert sorted(counter.ran) == ["T1-p1-t1.2", "T2-p1-t1.2"]


def test_parallel_equals_serial(scenario_file: Path, tmp_path: Path) -> None:
    grid = _grid(scenario_file)
    serial = lib.run(lib.plan(grid, tmp_path / "serial"), runner=fake_episode)
    parallel = lib.run(lib.plan(grid, tmp_path / "parallel"), runner=fake_episode, workers=2)
    assert _without_layout(_manifest(tmp_path / "serial")) == _without_layout(_manifest(tmp_path / "parallel"))
    assert _manifest(tmp_path / "parallel")["layout"]["workers"] == 2
    for ep in serial.episodes:
        a = json.loads((tmp_path / "serial" / ep.dir_name / "summary.json").read_text())
        b = json.loads((tmp_path / "parallel" / ep.dir_name / "summary.json").read_text())
        for volatile in ("wall_time_s",):
            a.pop(volatile), b.pop(volatile)
        assert a == b
    assert parallel.size == serial.size


def test_runner_errors(scenario_file: Path, tmp_path: Path) -> None:
    def broken(spec: Any) -> dict[str, Any]:
        if spec.options.lidar_sectors == 5:
            raise RuntimeError("planner bug")
        return fake_episode(spec)

    ab = lib.run(lib.plan(_grid(scenario_file), tmp_path / "ab"), runner=broken)
    errors = [e for e in ab.entries.values() if e.status == "error"]
    assert len(errors) == 4 and errors[0].error == "RuntimeError: planner bug"

    def no_key(spec: Any) -> dict[str, Any]:
        raise BadInputError("GEMINI_API_KEY is not set")

    with pytest.raises(BadInputError, match="GEMINI_API_KEY"):
        lib.run(lib.plan(_grid(scenario_file), tmp_path / "nokey"), runner=no_key)


def test_cli_dry_run_and_errors(scenario_file: Path, tmp_path: Path) -> None:
    cli = CliRunner()
    result = cli.invoke(
        app,
        [
            "ablate",
            "--scenario",
            str(scenario_file),
            "--tasks",
            "T1",
            "--poses",
            "1-2",
            "--lidar-sectors",
            "3,5,8",
            "--trials",
            "2",
            "--dry-run",
            "--out",
            str(tmp_path / "x"),
        ],
    )
    assert result.exit_code == 0, result.output
    assert "12 episodes" in result.output and "T1-p2-t2-lidar_sectors=8" in result.output
    assert not (tmp_path / "x").exists()
    grid = tmp_path / "g.yaml"
    grid.write_text(f"scenario: {scenario_file}\ntasks: T1\nposes: 1-2\nprompt: [full, short]\n")
    result = cli.invoke(app, ["ablate", "--grid", str(grid), "--dry-run", "--trials", "3"])
    assert result.exit_code == 0, result.output
    assert "12 episodes" in result.output
    grid.write_text("lidar_sectors: seven\n")
    bad = cli.invoke(app, ["ablate", "--grid", str(grid), "--dry-run"])
    assert bad.exit_code == 2 and len(bad.output.strip().splitlines()) == 1
    bad = cli.invoke(app, ["ablate", "--scenario", "nowhere", "--dry-run"])
    assert bad.exit_code == 2 and "nowhere" in bad.output


def test_any_planner_option_is_a_factor_the_tables_group_by(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from llmnav.cli import app

    small = str(Path(__file__).parents[1] / "runner" / "small_room.yaml")
    out = tmp_path / "abl"
    args = ["ablate", "--scenario", small, "--planner", "oracle", "--tasks", "T1", "--poses", "1", "-o",
            "max_iterations=3,4", "--out", str(out)]  # fmt: skip
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    assert "max_iterations=3" in result.output and "max_iterations=4" in result.output, result.output
    assert "max_iterations=None" not in result.output
    by = CliRunner().invoke(app, ["score", str(out), "--by", "max_iterations", "--format", "json"])
    assert by.exit_code == 0 and '"max_iterations": 3' in by.output, by.output
    bad = CliRunner().invoke(app, ["ablate", *args[1:-2], "-o", "max_iteratons=3", "--out", str(tmp_path / "b")])
    assert bad.exit_code == 2 and "max_iteratons" in bad.output and "no option of any planner" in bad.output


# --- where the model runs: a copy per worker, or one shared server ---------------------------------------


def test_layout_choice(monkeypatch: pytest.MonkeyPatch) -> None:
    from llmnav.ablate import layout as layouts

    monkeypatch.setitem(layouts.MEASURED, "shared", 2.0)
    monkeypatch.setitem(layouts.MEASURED, "per-worker", 1.0)
    shared = lib.choose(["local"], 2)
    assert shared.model == "shared" and shared.slots == 2 and shared.threads >= 1 and shared.model_path
    assert shared.model_path.endswith(".gguf") and "shared (picked)" in shared.describe()
    assert lib.choose(["local"], 2, requested="per-worker").model == "per-worker"
    assert lib.choose(["local"], 1).model == "in-process"  # one worker: nothing to share
    assert lib.choose(["policy:first", "policy:oracle"], 2).model == "none"  # no model at all
    assert lib.choose(["local:hf:/some/dir"], 2).model == "none"  # transformers models are not served
    assert lib.choose(["local"], 2, ray=True).model == "ray"
    assert lib.choose(["local"], 2, runs_backends=False).model == "runner's own"  # a custom runner, not asked
    assert lib.choose(["local"], 2, runs_backends=False, requested="shared").model == "shared"
    # measured slower: a copy per worker
    monkeypatch.setitem(layouts.MEASURED, "shared", 0.5)
    assert lib.choose(["local"], 2).model == "per-worker"
    monkeypatch.setitem(layouts.MEASURED, "shared", 2.0)
    monkeypatch.setenv("LLMNAV_LOCAL_THREADS", "3")
    assert lib.choose(["local"], 2).threads == 3


def test_auto_takes_the_layout_recorded_as_faster() -> None:
    """The measurement behind `auto` (bench.ablate): a copy per worker was faster than one shared copy."""
    from llmnav.ablate import layout as layouts

    assert layouts.faster() == max(layouts.MEASURED, key=layouts.MEASURED.__getitem__) == "per-worker"
    picked = lib.choose(["local"], 2)
    assert picked.model == "per-worker" and "measured faster" in picked.describe()


def test_cli_says_the_layout_on_one_stderr_line(
    scenario_file: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    asked: dict[str, Any] = {}

    def fake_run(ablation: Any, *, layout: str, on_layout: Any, **_: Any) -> Any:
        asked["layout"] = layout
        on_layout(lib.choose(["local"], 2, requested=layout))
        raise BadInputError("stop here")

    monkeypatch.setattr(lib, "run", fake_run)
    args = ["ablate", "--scenario", str(scenario_file), "--out", str(tmp_path / "x"), "--workers", "2"]
    result = CliRunner().invoke(app, [*args, "--model-layout", "shared"])
    assert asked["layout"] == "shared"
    said = [line for line in result.stderr.splitlines() if line.startswith("model layout")]
    assert len(said) == 1 and said[0].startswith("model layout: shared (as asked) — one loaded"), result.stderr
    result = CliRunner().invoke(app, args)
    assert asked["layout"] == "auto" and "model layout: per-worker (picked)" in result.stderr
    result = CliRunner().invoke(app, [*args, "--model-layout", "both"])
    assert result.exit_code == 2 and "--model-layout 'both'" in result.stderr


def _server_children() -> list[int]:
    """Pids of this process's children that are shared model servers."""
    import os

    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            cmdline = (entry / "cmdline").read_bytes().replace(b"\0", b" ")
            ppid = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, ValueError, IndexError):
            continue
        if b"llmnav.serve.shared" in cmdline and ppid == os.getpid():
            found.append(int(entry.name))
    return found


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads /proc")
def test_shared_layout_serves_the_workers_and_stops_after_the_sweep(scenario_file: Path, tmp_path: Path) -> None:
    grid = _grid(scenario_file, backend=["local"])
    lib.run(lib.plan(grid, tmp_path / "serial"), runner=fake_episode)
    seen: list[Any] = []
    ab = lib.run(
        lib.plan(grid, tmp_path / "shared"),
        runner=served_episode,
        workers=2,
        layout="shared",
        on_layout=seen.append,
        on_result=lambda *_: seen.append(_server_children()),
    )
    layout = seen[0]
    assert layout.model == "shared" and layout.slots == 2 and layout.chosen == "shared"
    assert all(len(pids) == 1 for pids in seen[1:]), seen  # one server, alive for every episode
    assert _server_children() == []  # and gone at the end
    assert all(e.status == "done" for e in ab.entries.values()), [e.error for e in ab.entries.values()]
    shared, serial = _manifest(tmp_path / "shared"), _manifest(tmp_path / "serial")
    assert _without_layout(shared) == _without_layout(serial)  # nothing else in the manifest changes
    assert shared["layout"] == layout.record() and shared["layout"]["model"] == "shared"
    assert serial["layout"]["model"] == "runner's own" and serial["layout"]["workers"] == 1


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads /proc")
def test_shared_server_stops_when_the_sweep_is_interrupted(scenario_file: Path, tmp_path: Path) -> None:
    servers: list[list[int]] = []

    def interrupt(*_: Any) -> None:
        servers.append(_server_children())
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        lib.run(
            lib.plan(_grid(scenario_file, backend=["local"]), tmp_path / "ab"),
            runner=served_episode,
            workers=2,
            layout="shared",
            on_result=interrupt,
        )
    assert len(servers[0]) == 1 and _server_children() == []
    manifest = _manifest(tmp_path / "ab")
    assert manifest["layout"]["model"] == "shared" and manifest["done"] >= 1  # resumable as ever
