"""`llmnav score --table runs` (a row per run, streamed), free-text tasks, ranged intervals, no empty columns."""

from __future__ import annotations

import csv
import io
import json
import sys
import tracemalloc
from pathlib import Path
from typing import Any

from typer.testing import CliRunner

sys.path.insert(0, str(Path(__file__).parent))
from score_fakes import config_for, write_run, write_scenario_file  # noqa: E402

from llmnav.cli import app  # noqa: E402
from llmnav.runs.folders import load_runs  # noqa: E402
from llmnav.runs.runlog import RunLog  # noqa: E402
from llmnav.scoring.runs_table import spool_rows, write_csv  # noqa: E402
from llmnav.scoring.score import compare_groups, select_table
from llmnav.scoring.tables import build_tables  # noqa: E402


def _free_config(text: str, target: dict[str, Any], scenario_file: Path) -> dict[str, Any]:
    """A run's config line for a task typed by a user: the shared id `adhoc`, its own text and target."""
    cfg = config_for("T1", start_pose_index=1, scenario_file=scenario_file)
    cfg["task"] = {"id": "adhoc", "text": text, "kind": "target", "targets": [target], "wording": "free"}
    return cfg


def _make(root: Path) -> None:
    root.mkdir(parents=True, exist_ok=True)
    sc = write_scenario_file(root.parent / f"{root.name}-tiny.yaml")
    for name, pose, end in (("b1", 1, [4.6, 0, 0]), ("b2", 2, [0.5, 3, 0])):
        cfg = config_for("T1", start_pose_index=pose, scenario_file=sc, options={"obstacles": [], "appearing": []})
        write_run(root / name, cfg, [cfg["start_pose"], end], summary=True)
    pellets = _free_config("head for the pellets", {"object": "pellets"}, sc)
    corner = _free_config("go to the far corner", {"point": [-8.0, 0.0]}, sc)
    write_run(root / "f1", pellets, [[0, 0, 0], [4.5, 0, 0]], summary=True)
    write_run(root / "f2", corner, [[0, 0, 0], [-7.5, 0, 0]], summary=True)


def _with_tokens(run_dir: Path) -> Path:
    """A run whose two model calls report prompt and completion tokens."""
    with RunLog(run_dir, config_for("T1")) as log:
        for step in (1, 2):
            reply = {"text": "{}", "latency_s": 0.1, "model": "m", "prompt_tokens": 100 * step,
                     "completion_tokens": 7, "meta": {}}  # fmt: skip
            log.event("llm_call", step=step, purpose="action", request={"messages": []}, reply=reply)
        log.event("pose", pose=[0, 0, 0])
        log.event("end", outcome="completed", reason="test", metrics={})
    return run_dir


def _csv(text: str) -> list[dict[str, str]]:
    return list(csv.DictReader(io.StringIO(text)))


def test_runs_table_a_row_per_run(tmp_path: Path) -> None:
    _make(tmp_path / "runs")
    _with_tokens(tmp_path / "runs" / "tok")
    result = CliRunner().invoke(app, ["score", str(tmp_path / "runs"), "--table", "runs", "--format", "csv"])
    assert result.exit_code == 0, result.output
    rows = _csv(result.stdout)
    assert [Path(r["run"]).name for r in rows] == ["b1", "b2", "f1", "f2", "tok"]
    by_name = {Path(r["run"]).name: r for r in rows}
    b2, f2, tok = by_name["b2"], by_name["f2"], by_name["tok"]
    assert (b2["scenario"], b2["task"], b2["task_id"], b2["start_pose_index"]) == ("tiny", "T1", "T1", "2")
    assert (b2["start_x_m"], b2["start_y_m"]) == ("0.0", "3.0")
    assert (b2["planner"], b2["backend"], b2["lidar_sectors"], b2["sensing"]) == (
        "stepwise",
        "replay:x",
        "8",
        "lidar+image",
    )
    assert b2["outcome"] == "completed" and b2["success"] == "False" and b2["failure_cause"] != ""
    b1 = by_name["b1"]
    assert b1["success"] == "True" and float(b1["score"]) > 0.9 and b1["failure_cause"] == ""
    assert float(b2["path_length_m"]) == 0.5 and b2["decisions"] != ""
    assert (f2["task"], f2["task_text"], f2["wording"], f2["task_id"]) == (
        "go to the far corner",
        "go to the far corner",
        "free",
        "",
    )
    assert (tok["prompt_tokens"], tok["completion_tokens"]) == ("300", "14")
    priced = load_runs([tmp_path / "runs" / "tok"])[0].summary  # the cost as llmnav prices the run
    assert (tok["cost_usd"], tok["cost_note"]) == (str(priced["cost_usd"]), priced["cost_note"])
    assert by_name["b1"]["prompt_tokens"] == ""  # not reported: unknown, not 0
    for column in rows[0]:  # a column with nothing to show is left out
        assert any(r[column] != "" for r in rows), column

    data = json.loads(
        CliRunner().invoke(app, ["score", str(tmp_path / "runs"), "--table", "runs", "--format", "json"]).stdout
    )
    assert data[0]["name"] == "runs" and len(data[0]["records"]) == 5
    assert data[0]["records"][1]["success"] is False and "obstacles" not in data[0]["records"][0]


def test_runs_table_bad_input(tmp_path: Path) -> None:
    _make(tmp_path)
    cli = CliRunner()
    for extra in (["--compare", "task=T1", "--compare", "task=T2"], ["--by", "prompt"]):
        bad = cli.invoke(app, ["score", str(tmp_path), "--table", "runs", *extra])
        assert bad.exit_code == 2 and len(bad.output.strip().splitlines()) == 1, bad.output
    bad = cli.invoke(app, ["score", str(tmp_path), "--table", "nope"])
    assert bad.exit_code == 2 and "runs" in bad.output and "Traceback" not in bad.output


def _bare_runs(root: Path, count: int) -> None:
    """`count` minimal finished runs (config line, end, summary), written directly: fast enough for thousands."""
    config = json.dumps({"type": "config", **config_for("T1")})
    end = json.dumps({"type": "end", "outcome": "completed", "reason": "test"})
    for index in range(count):
        folder = root / f"r{index:06d}"
        folder.mkdir(parents=True)
        (folder / "run.jsonl").write_text(f"{config}\n{end}\n")
        summary = {"outcome": "completed", "task_id": "T1", "task_text": "Go", "task_kind": "target",
                   "scenario": "tiny", "success": index % 2 == 0, "score": index / count, "spl": 0.5,
                   "soft_spl": 0.5, "oracle_success": True, "failure_cause": None, "collisions": 0,
                   "collided_with": [], "path_length_m": float(index), "success_radius_m": 2.5,
                   "closest_approach_m": 1.0, "shortest_path_m": 4.0, "goal_distance_m": 2.0}  # fmt: skip
        (folder / "summary.json").write_text(json.dumps(summary))


def _peak_bytes(root: Path) -> tuple[int, int]:
    tracemalloc.start()
    spool = spool_rows([root])
    write_csv(spool, io.StringIO() if spool.count < 0 else _Null())
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    spool.file.close()
    return spool.count, peak


class _Null(io.StringIO):
    def write(self, text: str) -> int:  # the CSV is not kept: only what the table itself holds is measured
        return len(text)


def test_runs_table_streams(tmp_path: Path) -> None:
    """Ten times the runs, about the same peak memory: no list of rows (or of run folders) is built."""
    _bare_runs(tmp_path / "small", 100)
    _bare_runs(tmp_path / "large", 1000)
    _peak_bytes(tmp_path / "small")  # warm the caches (scenario, imports) outside the measurement
    small = _peak_bytes(tmp_path / "small")
    large = _peak_bytes(tmp_path / "large")
    assert (small[0], large[0]) == (100, 1000)
    assert large[1] < 1.5 * small[1] + 200_000, (small, large)


def test_free_text_tasks_keyed_by_text(tmp_path: Path) -> None:
    _make(tmp_path)
    runs = load_runs([tmp_path])
    tables = build_tables(runs)
    episodes = select_table(tables, "episodes")
    assert sorted(r[0] for r in episodes.rows) == ["T1", "go to the far corner", "head for the pellets"]
    path = select_table(tables, "path")
    oracle = {r["task"]: r["oracle_length_m"] for r in path.records}
    assert oracle["go to the far corner"] is not None and oracle["head for the pellets"] is not None
    assert oracle["go to the far corner"]["mean"] != oracle["head for the pellets"]["mean"]  # each its own target
    assert not [p for r in runs for p in r.problems], [p for r in runs for p in r.problems]


def test_intervals_stay_in_range(tmp_path: Path) -> None:
    """n = 2, scores 0.03 and 0.99, both failed: the t interval would reach below 0 and above 1."""
    for name, end in (("a", [9.5, 0, 0]), ("b", [4.6, 0, 0]), ("c", [9.0, 0, 0]), ("d", [5.0, 0, 0])):
        cfg = config_for("T1", start_pose_index=1, options={"prompt": "full" if name in "ab" else "short"})
        write_run(tmp_path / name, cfg, [[0, 0, 0], end], summary=True)
    runs = load_runs([tmp_path])
    episodes = select_table(build_tables(runs), "episodes")
    for record in episodes.records:
        low, high = record["score"]["ci95"]
        assert 0.0 <= low <= high <= 1.0, record["score"]
        s_low, s_high = record["success_rate_ci95"]
        assert 0.0 <= s_low < record["success_rate"] < s_high <= 1.0 or record["success_rate"] in (0.0, 1.0)
        assert 0.0 <= s_low < s_high <= 1.0  # never a point, never outside the rate's range
    full = next(r for r in episodes.records if r["prompt"] == "full")
    assert full["score"]["ci95"][0] == 0.0 and full["score"]["ci95"][1] == 1.0  # clipped, not -5 .. 6
    _, results = compare_groups(runs, "prompt=full", "prompt=short")
    for item in results:
        for d in (item.result.a, item.result.b):
            if item.metric in ("score", "success", "spl", "soft_spl"):
                assert 0.0 <= d.ci_low <= d.ci_high <= 1.0, (item.metric, d)
            else:
                assert d.ci_low >= 0.0, (item.metric, d)


def test_no_empty_columns(tmp_path: Path) -> None:
    """No run reports new prompt tokens: the csv and json leave the column out instead of filling it with NaN."""
    _make(tmp_path)
    cli = CliRunner()
    text = cli.invoke(app, ["score", str(tmp_path), "--table", "episodes", "--format", "csv"]).stdout
    rows = _csv(text)
    assert rows and not any(c.startswith("new_prompt_tokens") for c in rows[0])
    for column in rows[0]:
        assert any(r[column] != "" for r in rows), column
    data = json.loads(cli.invoke(app, ["score", str(tmp_path), "--format", "json"]).stdout)
    for table in data:
        for key in {k for r in table["records"] for k in r}:
            assert any(r.get(key) is not None for r in table["records"]), (table["name"], key)
