"""Hostile folders: a run or sweep folder someone prepared with links, FIFOs, devices and junk.

Each case reproduces one way `view`, `score` or an ablation wrote through a planted link, embedded a file
from outside the run, blocked on a special file or crashed on a huge or deeply nested file. Property: no
file outside what llmnav writes is changed, nothing from outside the run is embedded, every command ends
(within a timeout) with exit 0 or a one-line error (exit 2) and no traceback.
Counted as category "hostile folders".
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

sys.path.insert(0, str(Path(__file__).parents[1] / "score"))
from score_fakes import config_for, write_scenario_file  # noqa: E402

from llmnav.cli import app  # noqa: E402
from llmnav.core.chat import Image  # noqa: E402
from llmnav.core.safefiles import IMAGE_LIMIT  # noqa: E402
from llmnav.errors import BadInputError  # noqa: E402
from llmnav.runs.locking import LOCK_FILE, FolderLock  # noqa: E402
from llmnav.runs.runlog import IMAGES_DIR, RUN_FILE, SUMMARY_FILE, RunLog, read_run  # noqa: E402

CATEGORY = "hostile folders"
LLMNAV = str(Path(sys.executable).parent / "llmnav")
SECRET = "-----BEGIN OPENSSH PRIVATE KEY----- hunter2"


def _jpeg() -> bytes:
    import cv2
    import numpy as np

    ok, data = cv2.imencode(".jpg", np.full((24, 32, 3), 128, np.uint8))
    assert ok
    return data.tobytes()


def make_run(run_dir: Path) -> tuple[Path, Path]:
    """A small complete run with one camera image; returns (run folder, the image's file)."""
    import base64

    image = Image(base64.b64encode(_jpeg()).decode("ascii"))
    with RunLog(run_dir, config_for("T1")) as log:
        digest = log.image(image)
        log.sim_time = 0.0
        log.event("pose", pose=[0.0, 0.0, 0.0])
        log.event("observation", step=1, pose=[0.0, 0.0, 0.0], image=digest)
        log.event("action", step=1, command="FRONT", parameters=1.0, pose_before=[0, 0, 0], pose_after=[1, 0, 0])
        log.sim_time = 1.0
        log.event("pose", pose=[1.0, 0.0, 0.0])
        log.event("end", outcome="completed", reason="test", metrics={})
    return run_dir, run_dir / IMAGES_DIR / f"{digest}.jpg"


def _victim(tmp_path: Path) -> Path:
    victim = tmp_path / "victim.txt"
    victim.write_text(SECRET)
    return victim


def _cli(*args: str) -> tuple[int, str]:
    result = CliRunner().invoke(app, list(args))
    text = result.output + (result.stderr if result.stderr_bytes is not None else "")
    assert "Traceback" not in text and not isinstance(result.exception, RecursionError), text
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    return result.exit_code, text


def _spawn(*args: str, timeout: float = 60) -> tuple[int, str]:
    """The CLI in its own process, so a command that blocks forever fails the test instead of hanging it."""
    done = subprocess.run([LLMNAV, *args], capture_output=True, text=True, timeout=timeout, stdin=subprocess.DEVNULL)
    assert "Traceback" not in done.stderr, done.stderr
    return done.returncode, done.stderr


def test_view_never_writes_through_a_planted_temporary_link(tmp_path: Path, tally) -> None:
    tally.add(CATEGORY, tried=2)
    victim = _victim(tmp_path)
    run, _ = make_run(tmp_path / "run")
    (run / "view.html.tmp").symlink_to(victim)
    code, text = _cli("view", str(run))
    assert code == 0, text
    assert victim.read_text() == SECRET
    sweep = tmp_path / "sweep"
    make_run(sweep / "a")
    make_run(sweep / "b")
    (sweep / "a" / "view.html.tmp").symlink_to(victim)
    (sweep / "b" / "view.html").symlink_to(victim)  # the page itself a link: replaced, not written through
    code, text = _cli("view", str(sweep))
    assert code == 0, text
    assert victim.read_text() == SECRET
    assert not (sweep / "b" / "view.html").is_symlink()


def test_a_lock_file_planted_as_a_link_is_refused_not_written(tmp_path: Path, tally) -> None:
    tally.add(CATEGORY, tried=1)
    victim = _victim(tmp_path)
    folder = tmp_path / "abl"
    folder.mkdir()
    (folder / LOCK_FILE).symlink_to(victim)
    with pytest.raises(BadInputError, match="symbolic link"):
        FolderLock(folder, "ablation folder")
    assert victim.read_text() == SECRET


def test_view_never_replaces_a_runs_own_files_nor_a_foreign_video(tmp_path: Path, tally) -> None:
    tally.add(CATEGORY, tried=4)
    run, image = make_run(tmp_path / "run")
    log = (run / RUN_FILE).read_bytes()
    for own in (run / RUN_FILE, run / SUMMARY_FILE):
        if not own.exists():
            own.write_text('{"outcome": "completed"}')
        before = own.read_bytes()
        code, text = _cli("view", str(run), "--out", str(own), "--force")
        assert code == 2 and "never replaces" in text, text
        assert own.read_bytes() == before
    mine = tmp_path / "mine.mp4"
    mine.write_bytes(b"my holiday video")
    code, text = _cli("view", str(run), "--out", str(tmp_path / "p.html"), "--video", str(mine))
    assert code == 2 and "--force" in text, text
    assert mine.read_bytes() == b"my holiday video"
    code, text = _cli("view", str(run), "--out", str(tmp_path / "p.html"), "--video", str(run / "trajectory.png.gif"))
    assert code == 0, text  # an ordinary new file inside the run is fine
    assert (run / RUN_FILE).read_bytes() == log


def test_view_embeds_no_file_from_outside_the_run_and_no_junk(tmp_path: Path, tally) -> None:
    tally.add(CATEGORY, tried=3)
    victim = _victim(tmp_path)
    for case in ("link", "not-an-image", "huge"):
        run, image = make_run(tmp_path / case)
        image.unlink()
        if case == "link":
            image.symlink_to(victim)
        elif case == "not-an-image":
            image.write_text(SECRET)
        else:
            image.write_bytes(b"\xff\xd8\xff" + b"\0" * (IMAGE_LIMIT + 1))
        code, text = _cli("view", str(run))
        assert code == 0, text
        page = (run / "view.html").read_bytes()
        import base64

        assert base64.b64encode(SECRET.encode()[:30])[:36] not in page
        assert len(page) < IMAGE_LIMIT, f"{case}: a {len(page)}-byte page"


@pytest.mark.parametrize("name", [RUN_FILE, SUMMARY_FILE])
def test_a_fifo_in_a_run_folder_never_blocks_view_or_score(tmp_path: Path, tally, name: str) -> None:
    tally.add(CATEGORY, tried=2)
    run, _ = make_run(tmp_path / "run")
    (run / name).unlink(missing_ok=True)
    os.mkfifo(run / name)
    for command in ("view", "score"):
        code, err = _spawn(command, str(run))
        if name == RUN_FILE:
            assert code == 2 and "not a regular file" in err, err
        else:  # a summary that cannot be read is recomputed from the log
            assert code == 0, err


def test_a_log_linked_to_dev_zero_is_refused(tmp_path: Path, tally) -> None:
    tally.add(CATEGORY, tried=2)
    run, _ = make_run(tmp_path / "run")
    (run / RUN_FILE).unlink()
    (run / RUN_FILE).symlink_to("/dev/zero")
    with pytest.raises(BadInputError, match="leads out of"):
        read_run(run)
    code, text = _cli("score", str(run))
    assert code == 2 and "leads out of" in text, text


def test_deeply_nested_json_in_a_log_or_summary_is_a_one_line_error(tmp_path: Path, tally) -> None:
    tally.add(CATEGORY, tried=4)
    run, _ = make_run(tmp_path / "run")
    lines = (run / RUN_FILE).read_text().splitlines()
    (run / RUN_FILE).write_text("\n".join([lines[0], "[" * 200_000, *lines[1:]]) + "\n")
    for command in ("view", "score"):
        code, text = _cli(command, str(run))
        assert code == 2 and "line 2" in text, text
    run2, _ = make_run(tmp_path / "run2")
    (run2 / SUMMARY_FILE).write_text("[" * 200_000)
    for command in ("view", "score"):
        code, text = _cli(command, str(run2))
        assert code == 0, text  # the summary counts as missing and is recomputed


def test_a_sweep_accepts_the_view_pages_llmnav_wrote(tmp_path: Path, tally) -> None:
    from llmnav import ablate as lib
    from llmnav.ablate.sweep import check_out_folder

    tally.add(CATEGORY, tried=2)
    scenario = str(write_scenario_file(tmp_path / "tiny.yaml"))
    grid = lib.grid_from_mapping({"scenario": scenario, "tasks": ["T1"], "backend": ["replay:x"]}, "test")
    root = tmp_path / "abl"
    make_run(root / "a")
    assert _cli("view", str(root))[0] == 0
    check_out_folder(root, lib.plan(grid, root))  # no "holds files that are not an ablation's (view.html)"
    (root / "notes.html").write_text("<p>mine</p>")
    with pytest.raises(BadInputError, match="notes.html"):
        check_out_folder(root, lib.plan(grid, root))
