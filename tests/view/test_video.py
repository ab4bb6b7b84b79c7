"""`llmnav view --video`: an MP4 (OpenCV) and a GIF (Pillow) whose frame count matches their duration."""

from __future__ import annotations

import subprocess
import sys

import pytest

from llmnav.errors import BadInputError
from llmnav.view.api import write_view

from .logs import decisions, video_slots

ENTRY = "from llmnav.cli import main; main()"


def test_mp4_holds_one_second_per_decision_at_10_fps(runs, tmp_path):
    import cv2

    out = tmp_path / "episode.mp4"
    result = subprocess.run(
        [sys.executable, "-c", ENTRY, "view", str(runs["stepwise"]), "--out", str(tmp_path / "p.html"),
         "--video", str(out)],
        capture_output=True, text=True, timeout=180,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    expected_frames = video_slots(runs["stepwise"]) * 10
    capture = cv2.VideoCapture(str(out))
    try:
        assert capture.isOpened()
        fps = capture.get(cv2.CAP_PROP_FPS)
        declared = int(capture.get(cv2.CAP_PROP_FRAME_COUNT))
        read, first = 0, None
        while True:
            ok, frame = capture.read()
            if not ok:
                break
            first = frame if first is None else first
            read += 1
    finally:
        capture.release()
    assert fps == pytest.approx(10.0)
    assert declared == read == expected_frames
    assert read / fps == pytest.approx(video_slots(runs["stepwise"]) * 1.0)
    assert first is not None and first.shape[1] == 1280 and first.std() > 20  # map beside camera, not blank
    assert f"{expected_frames} frames" in result.stderr and result.stdout.strip() == str(tmp_path / "p.html")


def test_gif_frame_count_and_durations_match(runs, tmp_path):
    from PIL import Image

    out = tmp_path / "episode.gif"
    info = write_view(runs["hybrid"], tmp_path / "p.html", video=out, fps=5, seconds_per_step=0.4).video
    assert info is not None
    expected_frames = video_slots(runs["hybrid"]) * 2
    with Image.open(out) as gif:
        frames = gif.n_frames
        durations = []
        for index in range(frames):
            gif.seek(index)
            durations.append(gif.info["duration"])
    assert frames == info.frames == expected_frames
    assert sum(durations) == pytest.approx(expected_frames * 200)  # [ms] 5 fps


def test_video_needs_mp4_or_gif(runs, tmp_path):
    with pytest.raises(BadInputError, match=r"\.mp4 or \.gif"):
        write_view(runs["hybrid"], tmp_path / "p.html", video=tmp_path / "x.avi")
    assert not (tmp_path / "p.html").exists()  # refused before anything was written


def test_mp4_falls_back_to_gif_when_no_codec_can_be_written(runs, tmp_path, monkeypatch):
    from llmnav.view import video

    monkeypatch.setattr(video, "CODECS", ("zzzz",))  # a codec no OpenCV build encodes
    info = write_view(runs["hybrid"], tmp_path / "p.html", video=tmp_path / "v.mp4", fps=5, seconds_per_step=0.2).video
    assert info is not None and info.path == tmp_path / "v.gif" and info.codec == "gif"
    assert (tmp_path / "v.gif").is_file() and not (tmp_path / "v.mp4").exists()


def test_waypoint_leg_lasts_one_slot_per_waypoint_driven(runs, tmp_path):
    from PIL import Image

    legs = decisions(runs["waypoints"])
    slots = video_slots(runs["waypoints"])
    assert slots > len(legs)  # the leg drove several waypoints
    info = write_view(
        runs["waypoints"], tmp_path / "p.html", video=tmp_path / "w.gif", fps=4, seconds_per_step=0.5
    ).video
    assert info is not None and info.frames == slots * 2
    with Image.open(tmp_path / "w.gif") as gif:
        assert gif.n_frames == slots * 2


def test_a_run_that_sent_no_image_still_shows_the_camera(runs, tmp_path):
    """The hybrid run reads LiDAR text only: the video renders the camera's view from each decision's pose."""
    import numpy as np
    from PIL import Image

    from llmnav.view.model import build_run_view

    assert not any(step.image for step in build_run_view(runs["hybrid"]).steps)  # nothing was sent
    out = tmp_path / "episode.gif"
    write_view(runs["hybrid"], tmp_path / "p.html", video=out, fps=2, seconds_per_step=0.5)
    with Image.open(out) as gif:
        gif.seek(0)
        frame = np.asarray(gif.convert("RGB"))
    height, width = frame.shape[:2]
    camera = frame[int(height * 0.1) : int(height * 0.8), width // 2 :]
    grey = np.all(np.abs(camera.astype(int) - 235) <= 6, axis=2).mean()
    assert grey < 0.3, f"{grey:.0%} of the camera half is the empty panel"
    assert len(np.unique(camera.reshape(-1, 3), axis=0)) > 12  # a picture (in the GIF palette), not a message
