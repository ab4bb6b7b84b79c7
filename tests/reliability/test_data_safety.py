"""Data safety: a result is never lost or mislabelled, whatever the user runs next or at the same time.

Each test reproduces one way results were lost or mislabelled on an earlier llmnav:
resume reusing another model's runs, a new seed deleting finished runs, two sweeps in one folder,
`score --out` onto its input, `--out` onto the working directory or a user's files, a corrupt log
stopping resume, workers outliving a killed sweep, and a model reply growing the log without bound.
Property: every finished run is kept byte for byte, every manifest entry points at a run of exactly its
condition, and a conflicting command stops with exit 2 and one line before it writes anything.
Counted as category "data safety"; `lost` counts results lost or mislabelled.
"""

from __future__ import annotations

import hashlib
import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from llmnav.runs.locking import LOCK_FILE

sys.path.insert(0, str(Path(__file__).parents[1] / "score"))
from score_fakes import CountingRunner, config_for, fake_episode, write_run, write_scenario_file  # noqa: E402

from llmnav import ablate as lib  # noqa: E402
from llmnav.cli import app  # noqa: E402
from llmnav.errors import BadInputError, FolderLockedError  # noqa: E402
from llmnav.runs.runlog import MAX_TEXT_CHARS, RUN_FILE, SUMMARY_FILE, SUPERSEDED_FILE, RunLog, read_run  # noqa: E402

CATEGORY = "data safety"
SMALL_ROOM = str(Path(__file__).parents[1] / "runner" / "small_room.yaml")
LLMNAV = str(Path(sys.executable).parent / "llmnav")


def tree(root: Path) -> dict[str, str]:
    """Relative path → sha256 of every file under root (lock files aside: they hold a pid)."""
    return {
        str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
        if p.is_file() and p.name != ".llmnav.lock"
    }


def kept(before: dict[str, str], after: dict[str, str]) -> list[str]:
    """Files of `before` that are gone or changed in `after` (manifest aside: it is rewritten)."""
    return [k for k, v in before.items() if k != "manifest.json" and after.get(k) != v]


def grid(scenario: Path, **extra: Any) -> lib.GridSpec:
    data = {"scenario": str(scenario), "tasks": ["T1", "T2"], "poses": [1], "trials": 1,
            "lidar_sectors": [3, 5], "seed": 0} | extra
    return lib.grid_from_mapping(data, "test")


def mislabelled(ablation: lib.Ablation) -> list[str]:
    """Manifest entries whose folder does not hold a run of exactly their episode's condition."""
    wrong = []
    manifest = json.loads((ablation.root / "manifest.json").read_text())
    by_key = {ep.key: ep for ep in ablation.episodes}
    for entry in manifest["episodes"]:
        if entry["status"] != "done":
            continue
        config = read_run(ablation.root / entry["dir"]).config
        ep = by_key[entry["key"]]
        if config.get("condition_hash") != ep.identity or config.get("backend") != ep.backend:
            wrong.append(entry["key"])
    return wrong


@pytest.fixture()
def scenario(tmp_path: Path) -> Path:
    return write_scenario_file(tmp_path / "tiny.yaml")


# --- 1. resume must compare the whole condition, not the backend's name ------------------------------


def test_resume_never_reuses_another_models_runs(scenario: Path, tmp_path: Path, tally: Any) -> None:
    out = tmp_path / "ab"
    model_a = grid(scenario, backend=["openai:model-a@http://127.0.0.1:9/v1"])
    model_b = grid(scenario, backend=["openai:model-b@http://127.0.0.1:9/v1"])
    lib.run(lib.plan(model_a, out), runner=fake_episode)
    before = tree(out)
    counter = CountingRunner()
    with pytest.raises(BadInputError, match="backend"):  # another grid in this folder: one line, no work
        lib.run(lib.plan(model_b, out), runner=counter)
    assert counter.ran == [] and tree(out) == before
    # without the manifest (removed by hand) the runs themselves say whose they are
    (out / "manifest.json").unlink()
    ab = lib.run(lib.plan(model_b, out), runner=counter)
    assert len(counter.ran) == ab.size, "model B reused model A's runs"
    wrong = mislabelled(ab)
    lost = kept(before, tree(out))
    tally.add(CATEGORY, tried=2, lost=len(wrong) + len(lost))
    assert not wrong and not lost


def test_edited_scenario_file_is_a_new_condition(scenario: Path, tmp_path: Path, tally: Any) -> None:
    out = tmp_path / "ab"
    lib.run(lib.plan(grid(scenario), out), runner=fake_episode)
    before = tree(out)
    scenario.write_text(scenario.read_text().replace("pile of pellets", "heap of pellets"))
    counter = CountingRunner()
    ab = lib.run(lib.plan(grid(scenario), out), runner=counter)
    assert len(counter.ran) == ab.size and all(name.endswith(".2") for name in counter.ran)
    wrong, lost = mislabelled(ab), kept(before, tree(out))
    tally.add(CATEGORY, tried=1, lost=len(wrong) + len(lost))
    assert not wrong and not lost


# --- 2. a new seed (any other grid) never deletes finished runs ---------------------------------------


def test_new_seed_keeps_finished_runs(scenario: Path, tmp_path: Path, tally: Any) -> None:
    out = tmp_path / "ab"
    lib.run(lib.plan(grid(scenario), out), runner=fake_episode)
    before = tree(out)
    cli = CliRunner().invoke(app, ["ablate", "--scenario", str(scenario), "--tasks", "T1,T2", "--poses", "1",
                                   "--lidar-sectors", "3,5", "--seed", "5", "--out", str(out)])
    assert cli.exit_code == 2, cli.output
    assert "seed" in cli.output and len(cli.output.strip().splitlines()) == 1
    assert tree(out) == before
    # the same through the library with the manifest gone: the new seed's episodes get their own folders
    (out / "manifest.json").unlink()
    ab = lib.run(lib.plan(grid(scenario, seed=5), out), runner=fake_episode)
    lost, wrong = kept(before, tree(out)), mislabelled(ab)
    tally.add(CATEGORY, tried=2, lost=len(lost) + len(wrong))
    assert not lost and not wrong


# --- 3. one writer per sweep folder and per run folder -------------------------------------------------


def test_run_folder_has_one_writer(tmp_path: Path, tally: Any) -> None:
    folder = tmp_path / "run"
    with RunLog(folder, {"note": "first"}) as first:
        first.event("pose", pose=[0, 0, 0])
        with pytest.raises(FolderLockedError, match=f"pid {os.getpid()}"):
            RunLog(folder, {"note": "second"})
    assert read_run(folder).config["note"] == "first"
    tally.add(CATEGORY, tried=1)


def test_run_log_create_is_atomic(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, tally: Any) -> None:
    """run.jsonl appearing between the check and the create (another writer) is never overwritten."""
    import llmnav.runs.runlog as runlog

    folder = tmp_path / "run"
    folder.mkdir()
    original = runlog.check_new_run_folder
    calls = {"n": 0}

    def racing_check(run_dir: Path) -> None:
        original(run_dir)
        calls["n"] += 1
        if calls["n"] == 2:  # the re-check passed; now another writer creates its log
            (folder / RUN_FILE).write_text('{"type": "config", "note": "other writer"}\n')

    monkeypatch.setattr(runlog, "check_new_run_folder", racing_check)
    with pytest.raises(BadInputError, match="already holds a run"):
        RunLog(folder, {"note": "late"})
    assert read_run(folder).config["note"] == "other writer"
    tally.add(CATEGORY, tried=1)


def ablate_cli(out: Path, *extra: str) -> list[str]:
    # 24 short episodes: the sweep holds its lock for seconds, longer than the second process takes to start
    # (8 episodes held it about 1.5 s, and on a loaded machine the second sometimes came after the end).
    return [LLMNAV, "ablate", "--scenario", SMALL_ROOM, "--tasks", "T1", "--poses", "1,2", "--trials", "6",
            "--planner", "oracle,frontier", "--out", str(out), *extra]


def concurrent_sweeps(tmp_path: Path, tries: int, tally: Any) -> None:
    problems = []
    for i in range(tries):
        out = tmp_path / f"sweep-{i}"
        first = subprocess.Popen(ablate_cli(out), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        # The second starts once the first holds the sweep's lock (its pid in the lock file): a fixed head
        # start lost the race on a loaded machine, and then the *first* was the one refused.
        lock, deadline = out / LOCK_FILE, time.monotonic() + 120
        while time.monotonic() < deadline and first.poll() is None:
            if lock.is_file() and lock.read_text(errors="replace").strip() == str(first.pid):
                break
            time.sleep(0.02)
        started = time.perf_counter()
        second = subprocess.run(ablate_cli(out), capture_output=True, text=True, timeout=300)
        second_s = time.perf_counter() - started
        first.communicate(timeout=600)
        bad = []
        if second.returncode == 0 and first.returncode == 0:
            # the first finished before the second started: the second found nothing to do (fine), but
            # then the sweep never overlapped and this try proves nothing
            bad.append("no overlap")
        elif second.returncode != 2 or f"pid {first.pid}" not in second.stderr:
            bad.append(f"second exit {second.returncode}: {second.stderr.strip()[-200:]}")
        if first.returncode != 0:
            bad.append(f"first exit {first.returncode}")
        manifest = json.loads((out / "manifest.json").read_text())
        for entry in manifest["episodes"]:
            summary = json.loads((out / entry["dir"] / SUMMARY_FILE).read_text())
            if entry["status"] != "done" or summary["outcome"] != entry["outcome"]:
                bad.append(f"{entry['key']}: manifest {entry['status']}/{entry['outcome']}, "
                           f"summary {summary['outcome']}")
        if bad:
            problems.append(f"try {i}: {bad}")
        tally.add(CATEGORY, tried=1, lost=1 if bad else 0)
        tally.note(CATEGORY, "second sweep refused after [s]", round(second_s, 2))
    assert not problems, problems


def test_concurrent_sweeps_quick(tmp_path: Path, tally: Any) -> None:
    concurrent_sweeps(tmp_path, 1, tally)


@pytest.mark.slow
@pytest.mark.reliability
def test_concurrent_sweeps_full(tmp_path: Path, tally: Any) -> None:
    concurrent_sweeps(tmp_path, 6, tally)


# --- 4. score --out never writes onto its input --------------------------------------------------------


def test_score_out_never_overwrites_a_run(scenario: Path, tmp_path: Path, tally: Any) -> None:
    run = write_run(tmp_path / "run", config_for("T1"), [[0, 0, 0], [1, 0, 0]], summary=True)
    before = tree(run)
    cli = CliRunner()
    for target in (run / RUN_FILE, run / SUMMARY_FILE, run / "tables.md", run / "images" / "x.csv"):
        result = cli.invoke(app, ["score", str(run), "--format", "md", "--out", str(target)])
        assert result.exit_code == 2 and ("run folder" in result.output or "input" in result.output), (
            target, result.output)
    given = tmp_path / "tables.md"
    given.write_text("my notes")
    result = cli.invoke(app, ["score", str(given.parent / "run"), str(given), "--out", str(given)])
    assert result.exit_code == 2 and given.read_text() == "my notes"
    assert tree(run) == before
    tally.add(CATEGORY, tried=5)


# --- 5. --out never lands on the working directory or on a user's files --------------------------------


def drive_cli(out: str) -> list[str]:
    return ["drive", "--planner", "oracle", "--scenario", SMALL_ROOM, "--task-id", "T1", "--out", out, "--json"]


def test_out_refuses_empty_path_and_a_users_folder(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                   tally: Any) -> None:
    monkeypatch.chdir(tmp_path)
    cli = CliRunner()
    result = cli.invoke(app, drive_cli(""))
    assert result.exit_code == 2 and "--out" in result.output, result.output
    assert list(tmp_path.iterdir()) == []
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / SUMMARY_FILE).write_text('{"my": "own"}')
    (mine / "trajectory.png").write_bytes(b"my picture")
    before = tree(mine)
    result = cli.invoke(app, drive_cli(str(mine)))
    assert result.exit_code == 2 and "not empty" in result.output, result.output
    assert tree(mine) == before and not (mine / RUN_FILE).exists()
    # an ablation into a folder of other files is refused as well
    result = cli.invoke(app, ["ablate", "--scenario", SMALL_ROOM, "--planner", "oracle", "--out", str(mine)])
    assert result.exit_code == 2 and tree(mine) == before, result.output
    tally.add(CATEGORY, tried=3)


# --- 6. a corrupt log makes its episode unfinished; the damaged folder is kept and named ----------------


def test_corrupt_log_is_kept_and_its_episode_rerun(scenario: Path, tmp_path: Path, tally: Any) -> None:
    out = tmp_path / "ab"
    first = lib.run(lib.plan(grid(scenario), out), runner=fake_episode)
    damaged = out / first.entries[first.episodes[1].key].dir
    (damaged / RUN_FILE).write_bytes(random.Random(6).randbytes(500))
    before = tree(out)
    counter = CountingRunner()
    ab = lib.run(lib.plan(grid(scenario), out), runner=counter)
    assert counter.ran == [damaged.name + ".2"]
    assert [name for name, _ in ab.kept] == [damaged.name] and "damaged" in ab.kept[0][1]
    assert json.loads((damaged / SUPERSEDED_FILE).read_text())["replaced_by"] == damaged.name + ".2"
    entry = ab.entries[ab.episodes[1].key]
    assert entry.status == "done" and entry.dir == damaged.name + ".2" and entry.kept
    lost, wrong = kept(before, tree(out)), mislabelled(ab)
    # score skips the superseded folder (it is no result), so the tables count each episode once
    result = CliRunner().invoke(app, ["score", str(out), "--format", "json"])
    assert result.exit_code == 0, result.output
    tally.add(CATEGORY, tried=1, lost=len(lost) + len(wrong))
    assert not lost and not wrong


def test_cli_names_the_damaged_folder(tmp_path: Path, tally: Any) -> None:
    out = tmp_path / "ab"
    args = ["ablate", "--scenario", SMALL_ROOM, "--tasks", "T1", "--poses", "1", "--planner", "oracle",
            "--out", str(out)]
    assert CliRunner().invoke(app, args).exit_code == 0
    (run_dir,) = [p for p in out.iterdir() if p.is_dir()]
    (run_dir / RUN_FILE).write_bytes(b"\xff\xfe" + random.Random(1).randbytes(498))
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    assert f"kept {run_dir}" in " ".join(result.output.split()), result.output
    assert (out / (run_dir.name + ".2") / SUMMARY_FILE).exists()
    tally.add(CATEGORY, tried=1)


# --- 7. workers die with their parent -------------------------------------------------------------------


def descendants(pid: int) -> set[int]:
    """Every live process below `pid` (from /proc)."""
    children: dict[int, list[int]] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        children.setdefault(int(fields[1]), []).append(int(stat.parent.name))
    found: set[int] = set()
    todo = [pid]
    while todo:
        for child in children.get(todo.pop(), []):
            if child not in found:
                found.add(child)
                todo.append(child)
    return found


def alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_workers_exit_when_the_sweep_is_killed(tmp_path: Path, tally: Any) -> None:
    out = tmp_path / "ab"
    proc = subprocess.Popen(ablate_cli(out, "--workers", "2", "--trials", "6"), stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        deadline = time.perf_counter() + 120
        below: set[int] = set()
        while time.perf_counter() < deadline and len(below) < 3:  # two workers and the resource tracker
            below = descendants(proc.pid)
            time.sleep(0.05)
        assert len(below) >= 2, f"workers never started: {below}"
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)
        deadline = time.perf_counter() + 10
        while time.perf_counter() < deadline and any(alive(p) for p in below):
            time.sleep(0.05)
        survivors = [p for p in below if alive(p)]
        tally.add(CATEGORY, tried=1, lost=1 if survivors else 0)
        assert not survivors, f"{len(survivors)} of {len(below)} processes outlived the sweep"
    finally:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass


# --- 8. logged text is capped per message ---------------------------------------------------------------


def test_huge_reply_is_capped_in_the_log(tmp_path: Path, tally: Any) -> None:
    reply = "{" + "x" * 30_000_000 + "}"
    digest = hashlib.sha256(reply.encode()).hexdigest()
    with RunLog(tmp_path / "run", {"note": "huge"}) as log:
        for attempt in range(4):  # the reply, then three corrections that re-send it
            messages = [{"role": "assistant", "content": reply}] * attempt
            log.event("llm_call", step=1, purpose="correction" if attempt else "action",
                      request={"messages": messages}, reply={"text": reply, "latency_s": 1.0})
    size = (tmp_path / "run" / RUN_FILE).stat().st_size
    assert size < 10 * MAX_TEXT_CHARS * 1.2, f"log is {size / 1e6:.1f} MB"
    calls = read_run(tmp_path / "run").of_type("llm_call")
    last = calls[-1]
    assert {c["field"] for c in last["truncated"]} == {"reply.text", *(f"request.messages[{i}].content"
                                                                        for i in range(3))}
    assert all(c["chars"] == len(reply) and c["sha256"] == digest for c in last["truncated"])
    text = last["reply"]["text"]
    assert text.startswith("{xxx") and text.endswith("xx}") and "not logged" in text
    tally.add(CATEGORY, tried=1)


# --- aborted by a backend failure: an error, retried; aborted by the model's answers: a result ------------


def aborting_runner(failure: str | None, ran: list[str]) -> Any:
    """A runner whose episodes all end "aborted", marked as the runner marks them (or not at all)."""
    from score_fakes import tiny_scenario

    from llmnav.runs.runlog import write_json_atomic
    from llmnav.scoring.metrics import summarize_run

    def run(spec: Any) -> dict[str, Any]:
        ran.append(Path(spec.out_dir).name)
        options = spec.options.model_dump(mode="json")
        config = config_for(spec.task_id, options=options, start_pose_index=spec.start_pose, seed=options["seed"],
                            backend=spec.backend, condition=spec.condition)
        metrics = {"failure": failure} if failure else {}
        write_run(Path(spec.out_dir), config, [[0.0, 0.0, 0.0]], outcome="aborted", metrics=metrics)
        summary = summarize_run(read_run(Path(spec.out_dir)), tiny_scenario())
        write_json_atomic(Path(spec.out_dir) / SUMMARY_FILE, summary)
        return summary

    return run


def test_backend_failures_are_errors_and_retried(scenario: Path, tmp_path: Path, tally: Any) -> None:
    out = tmp_path / "ab"
    first: list[str] = []
    ab = lib.run(lib.plan(grid(scenario), out), runner=aborting_runner("backend", first))
    assert ab.counts() == (0, 0, ab.size)  # no episode done, every one an error
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["done"] == 0 and manifest["errors"] == ab.size
    assert all(e["status"] == "error" and e["error"].startswith("aborted") for e in manifest["episodes"])
    before = tree(out)
    counter = CountingRunner()
    again = lib.run(lib.plan(grid(scenario), out), runner=counter)
    assert sorted(counter.ran) == sorted(name + ".2" for name in first)  # retried, into new folders
    assert again.counts()[0] == again.size and not kept(before, tree(out)) and not mislabelled(again)
    # the planner's own "aborted" (the model never gave a valid action) is a result: kept, not rerun
    model_out = tmp_path / "model"
    lib.run(lib.plan(grid(scenario), model_out), runner=aborting_runner(None, []))
    rerun = CountingRunner()
    done = lib.run(lib.plan(grid(scenario), model_out), runner=rerun)
    assert rerun.ran == [] and done.counts()[0] == done.size
    tally.add(CATEGORY, tried=2)


DAMAGES = {
    "random bytes": lambda data, rng: rng.randbytes(500),
    "empty": lambda data, rng: b"",
    "truncated": lambda data, rng: data[: rng.randrange(1, max(2, len(data)))],
    "not utf-8": lambda data, rng: b"\xff" + data[1:],
    "nul bytes": lambda data, rng: b"\x00" * len(data),
}


def damage_and_resume(scenario: Path, tmp_path: Path, rounds: int, seed: int, tally: Any) -> None:
    """Damage random files of finished episodes, resume, and check nothing is lost or mislabelled."""
    rng = random.Random(seed)
    problems = []
    for i in range(rounds):
        out = tmp_path / f"ab-{i}"
        ab = lib.run(lib.plan(grid(scenario), out), runner=fake_episode)
        victims = rng.sample(ab.episodes, rng.randint(1, len(ab.episodes)))
        for ep in victims:
            name = rng.choice([RUN_FILE, SUMMARY_FILE])
            path = out / ab.entries[ep.key].dir / name
            kind = rng.choice(sorted(DAMAGES))
            path.write_bytes(DAMAGES[kind](path.read_bytes(), rng))
        before = tree(out)
        resumed = lib.run(lib.plan(grid(scenario), out), runner=fake_episode)
        lost, wrong = kept(before, tree(out)), mislabelled(resumed)
        not_done = [k for k, e in resumed.entries.items() if e.status != "done"]
        if lost or wrong or not_done:
            problems.append(f"round {i}: lost {lost}, mislabelled {wrong}, not done {not_done}")
        tally.add(CATEGORY, tried=1, lost=len(lost) + len(wrong))
    assert not problems, problems[:3]


def test_damaged_runs_resume_quick(scenario: Path, tmp_path: Path, tally: Any) -> None:
    damage_and_resume(scenario, tmp_path, 2, seed=1, tally=tally)


@pytest.mark.slow
@pytest.mark.reliability
def test_damaged_runs_resume_full(scenario: Path, tmp_path: Path, tally: Any) -> None:
    damage_and_resume(scenario, tmp_path, 25, seed=2, tally=tally)
