"""`llmnav view` pages without a browser: content, escaping of hostile model text, partial logs, size,
bad input and the refusal to overwrite files that are not ours."""

from __future__ import annotations

import re
import subprocess
import sys

import pytest
from markupsafe import escape

from llmnav.errors import BadInputError
from llmnav.view.api import write_view

from .conftest import HOSTILE
from .logs import decisions, events, last_reply

ENTRY = "from llmnav.cli import main; main()"


def llmnav(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-c", ENTRY, *args], capture_output=True, text=True, timeout=180)


def step_buttons(page: str) -> list[str]:
    return re.findall(r'<button type="button" data-step="(\d+)"', page)


@pytest.mark.parametrize("kind", ["stepwise", "hybrid", "fsm", "waypoints", "killed"])
def test_one_entry_per_decision_and_every_reply_is_on_the_page(runs, tmp_path, kind):
    out = write_view(runs[kind], tmp_path / f"{kind}.html").page
    page = out.read_text(encoding="utf-8")
    keys = decisions(runs[kind])
    assert keys, "the fixture run logged no decision"
    assert step_buttons(page) == [str(i) for i in range(len(keys))]
    assert len(re.findall(r'<section class="step" ', page)) == len(keys)
    for key in keys:
        reply = last_reply(runs[kind], key)
        if reply is not None:
            assert str(escape(reply)) in page


def test_hostile_model_text_is_escaped_everywhere(runs, tmp_path):
    page = write_view(runs["stepwise"], tmp_path / "p.html").page.read_text(encoding="utf-8")
    assert any(
        HOSTILE in e.get("reply", {}).get("text", "") for e in events(runs["stepwise"]) if e["type"] == "llm_call"
    )
    assert HOSTILE not in page
    assert "<script>alert" not in page and "onerror=alert(2)>" not in page
    assert "&lt;/script&gt;&lt;script&gt;alert(1)&lt;/script&gt;" in page
    # exactly one script element: the page's own
    assert page.count("<script") == 1


def test_header_and_camera_images_and_sectors(runs, tmp_path):
    page = write_view(runs["stepwise"], tmp_path / "p.html").page.read_text(encoding="utf-8")
    images = list((runs["stepwise"] / "images").glob("*.jpg"))
    assert images and page.count("data:image/jpeg;base64,") == len(images)
    assert "Go to the red box" in page and "stepwise" in page and "completed" in page
    assert page.count('class="wedge ') >= 8  # the default 8 LiDAR sectors of the first observation
    assert 'alt="Camera image sent to the model at step 1' in page


def test_an_image_a_text_only_backend_never_got_is_not_called_sent(runs, tmp_path):
    import json
    import shutil

    run = tmp_path / "text-only"
    shutil.copytree(runs["stepwise"], run)
    log = run / "run.jsonl"
    lines = log.read_text(encoding="utf-8").splitlines()
    config = json.loads(lines[0])
    assert config.get("modality") == "multimodal"  # the fixture's replay backend took the images
    config["modality"] = "text"
    log.write_text("\n".join([json.dumps(config), *lines[1:]]) + "\n", encoding="utf-8")
    page = write_view(run, tmp_path / "t.html").page.read_text(encoding="utf-8")
    assert "Camera image sent" not in page and "camera image sent" not in page
    assert page.count("not sent: the model reads text only") >= 2  # caption and alt text of each image


def test_killed_run_says_what_is_missing(runs, tmp_path):
    page = write_view(runs["killed"], tmp_path / "k.html").page.read_text(encoding="utf-8")
    assert "no end event" in page and "summary.json is missing" in page
    assert "incomplete last line" in page
    assert "no action logged" in page  # the cut step


def test_fsm_page_has_profile_and_suggestion_outcomes(runs, tmp_path):
    page = write_view(runs["fsm"], tmp_path / "f.html").page.read_text(encoding="utf-8")
    verdicts = [e["verdict"] for e in events(runs["fsm"]) if e.get("kind") == "suggestion"]
    assert {"accepted", "parse", "bounds"} <= set(verdicts)
    assert '<img class="chart" src="data:image/png;base64,' in page and 'alt="FSM command profile' in page
    for verdict in set(verdicts):
        assert f'class="mark-{verdict}"' in page


def test_waypoint_page_shows_attempts_and_replans(runs, tmp_path):
    page = write_view(runs["waypoints"], tmp_path / "w.html").page.read_text(encoding="utf-8")
    attempts = [e for e in events(runs["waypoints"]) if e.get("kind") == "waypoint_attempt"]
    replans = [e for e in events(runs["waypoints"]) if e.get("kind") == "replan"]
    assert any(not a["valid"] for a in attempts) and replans
    assert page.count('class="attempt"') + page.count('class="attempt valid"') == sum(
        1 for a in attempts if a["points"]
    )
    assert page.count('class="replan"') == sum(1 for r in replans if r.get("obstacle"))


def test_sweep_page_links_every_run_and_writes_missing_run_pages(sweep, tmp_path):
    from urllib.parse import quote

    result = write_view(sweep)
    page = result.page.read_text(encoding="utf-8")
    assert result.kind == "sweep" and result.page == sweep / "view.html"
    run_dirs = sorted(p.parent for p in sweep.rglob("run.jsonl"))
    assert len(run_dirs) == 4
    for run_dir in run_dirs:
        assert (run_dir / "view.html").is_file()
        assert f'href="./{quote(run_dir.name)}/view.html"' in page
    assert "Episodes (stepwise source" in page and page.count('<th scope="row" class="bar-label">') == 2
    assert page.count('class="success-map"') == 2  # lidar_sectors=3 and =8


def test_thirty_step_page_with_640x480_images_stays_small(runs, tmp_path):
    """30 decisions shaped like the recorded stepwise run's first one, each with its own 640×480 camera JPEG
    and the whole history re-sent (`--history all`: request k holds every earlier exchange)."""
    import json

    import cv2
    import numpy as np

    src = runs["stepwise"]
    lines = [json.loads(line) for line in (src / "run.jsonl").read_text().splitlines()]
    step1 = [e for e in lines if e.get("step") == 1]
    first_call = next(e for e in step1 if e["type"] == "llm_call")
    system, turn = first_call["request"]["messages"][0], first_call["request"]["messages"][-1]
    run = tmp_path / "thirty"
    (run / "images").mkdir(parents=True)
    out_lines = [lines[0]]
    history: list[dict] = []
    rng = np.random.default_rng(0)
    for k in range(1, 31):
        # a noisy picture compresses like a camera frame, not like a flat colour
        picture = (rng.normal(128, 40, (480, 640, 3)).clip(0, 255)).astype(np.uint8)
        picture = cv2.GaussianBlur(picture, (0, 0), 2.0)
        ok, jpeg = cv2.imencode(".jpg", picture, [cv2.IMWRITE_JPEG_QUALITY, 80])
        digest = f"{k:064x}"
        (run / "images" / f"{digest}.jpg").write_bytes(jpeg.tobytes())
        user = dict(turn, images=[digest])
        for e in step1:
            e = dict(e, step=k)
            if e["type"] == "observation":
                e["image"] = digest
            if e["type"] == "llm_call":
                e = dict(e, request=dict(e["request"], messages=[system, *history, user]))
            out_lines.append(e)
        history += [user, {"role": "assistant", "text": first_call["reply"]["text"]}]
    (run / "run.jsonl").write_text("\n".join(json.dumps(e) for e in out_lines) + "\n")
    page = write_view(run, tmp_path / "thirty.html").page
    images = sum(p.stat().st_size for p in (run / "images").iterdir())
    assert len(step_buttons(page.read_text(encoding="utf-8"))) == 30
    assert page.stat().st_size < 5_000_000, (page.stat().st_size, images)


def test_not_a_run_nor_a_sweep_is_one_line_exit_2(tmp_path):
    (tmp_path / "empty").mkdir()
    for target in (tmp_path / "empty", tmp_path / "absent"):
        result = llmnav("view", str(target))
        assert result.returncode == 2, result.stderr
        assert len(result.stderr.strip().splitlines()) == 1 and "Traceback" not in result.stderr


def test_unreadable_log_is_one_line_exit_2(tmp_path):
    run = tmp_path / "broken"
    run.mkdir()
    (run / "run.jsonl").write_text('{"type": "config"}\nnot json at all\n{"type": "end"}\n')
    result = llmnav("view", str(run))
    assert result.returncode == 2 and "line 2" in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1 and "Traceback" not in result.stderr


def test_out_onto_a_foreign_file_is_refused_unless_forced(runs, tmp_path):
    foreign = tmp_path / "notes.html"
    foreign.write_text("my own notes")
    with pytest.raises(BadInputError, match="--force"):
        write_view(runs["hybrid"], foreign)
    assert foreign.read_text() == "my own notes"
    result = llmnav("view", str(runs["hybrid"]), "--out", str(foreign))
    assert result.returncode == 2 and foreign.read_text() == "my own notes"
    # our own page may be rewritten; a foreign one only with --force
    ours = write_view(runs["hybrid"], tmp_path / "ours.html").page
    write_view(runs["hybrid"], ours)
    write_view(runs["hybrid"], foreign, force=True)
    assert '<meta name="generator" content="llmnav view">' in foreign.read_text()


def test_drive_view_writes_the_page_and_prints_its_path(tmp_path):
    from .conftest import SMALL

    out = tmp_path / "run"
    result = llmnav(
        "drive", "--scenario", SMALL, "--task-id", "T1", "--planner", "oracle", "--out", str(out), "--view", "--json"
    )
    assert result.returncode == 0, result.stderr
    page = out / "view.html"
    assert f"page: {page}" in result.stderr and page.is_file()
    assert "page:" not in result.stdout  # --json keeps stdout to the summary
    assert len(step_buttons(page.read_text(encoding="utf-8"))) == len(decisions(out))


def test_run_whose_scenario_is_gone_still_gets_a_page(runs, tmp_path):
    import json
    import shutil

    run = tmp_path / "moved"
    shutil.copytree(runs["hybrid"], run, ignore=shutil.ignore_patterns("view.html"))
    lines = (run / "run.jsonl").read_text(encoding="utf-8").splitlines()
    config = json.loads(lines[0])
    config.update(scenario="nowhere", scenario_file=str(tmp_path / "gone.yaml"))
    (run / "run.jsonl").write_text("\n".join([json.dumps(config), *lines[1:]]) + "\n", encoding="utf-8")
    page = write_view(run, tmp_path / "m.html").page.read_text(encoding="utf-8")
    assert "cannot be loaded: no map is drawn" in page
    assert len(step_buttons(page)) == len(decisions(run))
    assert 'class="trajectory"' in page  # the driven path is still drawn


def test_video_of_a_sweep_is_refused(sweep, tmp_path):
    with pytest.raises(BadInputError, match="needs a run folder"):
        write_view(sweep, tmp_path / "s.html", video=tmp_path / "s.mp4")


def test_odd_field_types_in_a_log_do_not_break_the_page(runs, tmp_path):
    """A log edited by hand or written by another version: wrong types show as text, never crash."""
    import json

    config = json.loads((runs["stepwise"] / "run.jsonl").read_text(encoding="utf-8").splitlines()[0])
    odd = [
        {"type": "observation", "step": 1, "pose": "here", "lidar_text": 42, "detections": "none", "image": 7},
        {"type": "llm_call", "step": 1, "purpose": None, "request": {"messages": "x"}, "reply": "plain"},
        {"type": "llm_call", "step": 1, "request": None, "reply": {"text": None, "latency_s": "slow"}},
        {"type": "guard", "step": 1, "outcome": None, "error": {"nested": True}, "attempt": "first"},
        {"type": "action", "step": 1, "command": None, "parameters": {"a": 1}, "pose_before": [1], "pose_after": None},
        {"type": "planner", "step": 1, "kind": "waypoint_attempt", "points": "none", "valid": "yes"},
        {"type": "planner", "step": 1, "kind": "waypoint_attempt", "points": [["a", "b"], [1, 2], 3], "problems": 5},
        {"type": "planner", "step": 1, "kind": "replan", "pose": [1, 2], "obstacle": "far"},
        {"type": "planner", "step": 1, "kind": "replan", "pose": ["x", 2, 3], "obstacle": ["a", "b"]},
        {"type": "action", "step": "two", "command": "FRONT", "parameters": 1.0},
        {"type": "pose", "pose": [1.0]},
        {"type": "end"},
    ]
    run = tmp_path / "odd"
    run.mkdir()
    (run / "run.jsonl").write_text("\n".join(json.dumps(e) for e in [config, *odd]) + "\n", encoding="utf-8")
    result = write_view(run, tmp_path / "o.html", video=tmp_path / "o.gif", fps=2, seconds_per_step=0.5)
    assert step_buttons(result.page.read_text(encoding="utf-8")) == ["0", "1"]  # step 1 and step "two"
    assert result.video is not None and result.video.frames == 2


def test_an_image_name_in_the_log_cannot_reach_outside_the_images_folder(runs, tmp_path):
    import json

    secret = tmp_path / "secret.jpg"
    secret.write_bytes(b"\xff\xd8 not for the page \xff\xd9")
    run = tmp_path / "run"
    (run / "images").mkdir(parents=True)
    config = json.loads((runs["stepwise"] / "run.jsonl").read_text(encoding="utf-8").splitlines()[0])
    sneaky = {"type": "observation", "step": 1, "pose": [1.0, 1.0, 0.0], "image": "../../secret"}
    (run / "run.jsonl").write_text(json.dumps(config) + "\n" + json.dumps(sneaky) + "\n", encoding="utf-8")
    assert (run / "images" / "../../secret.jpg").resolve() == secret.resolve()
    page = write_view(run, tmp_path / "p.html").page.read_text(encoding="utf-8")
    assert "data:image/jpeg" not in page and "is missing from the run folder" in page


def test_sweep_links_stay_paths_whatever_a_folder_is_called(runs, tmp_path):
    import shutil

    root = tmp_path / "sweep"
    shutil.copytree(runs["hybrid"], root / "javascript:alert(1)", ignore=shutil.ignore_patterns("view.html"))
    page = write_view(root).page.read_text(encoding="utf-8")
    assert 'href="./javascript%3Aalert%281%29/view.html"' in page
    assert 'href="javascript:' not in page


def test_ablate_view_writes_the_sweep_page(tmp_path):
    from .conftest import SMALL

    out = tmp_path / "sweep"
    args = ("ablate", "--scenario", SMALL, "--tasks", "T1", "--poses", "1", "--planner", "oracle", "--out", str(out))
    result = llmnav(*args, "--view")
    assert result.returncode == 0, result.stderr
    assert f"page: {out / 'view.html'}" in " ".join(result.stdout.split())
    page = (out / "view.html").read_text(encoding="utf-8")
    assert page.count('<table class="runs"') == 1 and (out / "T1-p1-t1" / "view.html").is_file()
