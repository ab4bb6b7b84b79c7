"""An episode as a video: the top view with the moving robot beside the camera frame, and a caption.

Each decision gets `seconds_per_step` of video per executed action (at least one: a waypoint leg that
drives five waypoints lasts five times as long as a turn). The robot moves along the trajectory
samples logged between this decision and the next, the right half shows the camera image sent, and the
caption names the decision, the executed action and the model's one-line reasoning. The map is drawn
once (`llmnav.view.basemap`, which uses `llmnav.reporting.topview`); frames are composed with OpenCV.

MP4 goes through OpenCV's VideoWriter with the first codec this OpenCV build can write (`CODECS`);
GIF through Pillow (matplotlib's own dependency), at half size. When no MP4 codec can be written, the
video falls back to a GIF beside the asked path (same name, .gif), and `VideoInfo.path` says so.
Either way the file holds exactly `frames` frames at `fps`, so its duration is frames / fps.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from llmnav.core.geometry import Pose2D
from llmnav.core.safefiles import IMAGE_LIMIT, UnsafeFileError, image_kind, private_dir, read_bytes
from llmnav.errors import BadInputError
from llmnav.view.basemap import draw_base_map
from llmnav.view.model import as_pose

if TYPE_CHECKING:
    import numpy as np

    from llmnav.view.model import RunView, StepView

PANEL_W, PANEL_H = 640, 480  # [px] each half of the picture
CAPTION_H = 72  # [px] caption bar under the picture
CODECS = ("avc1", "mp4v")  # H.264 when the build has an encoder for it, else MPEG-4 part 2
GIF_SCALE = 0.5  # GIFs are large: half size
ROBOT_PX = 9  # [px] robot marker radius on the map
_FFMPEG_LOG_ENV = "OPENCV_FFMPEG_LOGLEVEL"


@dataclass
class VideoInfo:
    """What was written."""

    path: Path
    frames: int
    fps: float
    codec: str
    width: int
    height: int

    @property
    def duration_s(self) -> float:
        """[s] frames / fps."""
        return self.frames / self.fps


class CameraRenderer:
    """The run's world rebuilt for the video: the camera's view from a logged pose, for decisions that sent none.

    Most runs send the model text only (the default sensing is LiDAR), so their logs hold no picture; the
    video renders one (PyBullet's TinyRenderer, as the robot's camera) at the pose each decision started
    from. Obstacles placed from the start are rebuilt too; those that appear later are not.
    """

    def __init__(self, view: RunView) -> None:
        self.view = view
        self._world: Any = None
        self.failed = view.scenario is None

    def render(self, pose: list[float] | None) -> np.ndarray | None:
        """The BGR view from `pose` [x, y, yaw], or None (no scenario or pose, or the world cannot be built)."""
        if self.failed or pose is None or len(pose) < 3:
            return None
        # deferred: numpy (about 0.1 s) loads only when camera views are rendered
        import numpy as np

        try:
            if self._world is None:
                self._world = self._build()
            self._world.reset(Pose2D(float(pose[0]), float(pose[1]), float(pose[2])))
            rgb = self._world.camera.capture(width=PANEL_W, height=PANEL_H).rgb
        except Exception:  # noqa: BLE001 — no picture is the panel's own message, never a failed video
            self.failed = True
            return None
        return np.ascontiguousarray(np.asarray(rgb)[:, :, 2::-1])

    def _build(self) -> Any:
        # deferred: pybullet (about 0.1 s) loads only when camera views are rendered
        from llmnav.sim.world import World

        assert self.view.scenario is not None
        world = World(self.view.scenario)
        options = self.view.config.get("options")
        for item in options.get("obstacles") or [] if isinstance(options, dict) else []:
            if isinstance(item, list) and len(item) >= 2:
                world.add_obstacle(float(item[0]), float(item[1]))
        return world

    def close(self) -> None:
        """Disconnect the rebuilt world."""
        if self._world is not None:
            self._world.close()
            self._world = None


def _camera(view: RunView, step: StepView | None, renderer: CameraRenderer | None = None) -> np.ndarray:
    """The camera image of a decision fitted into the right panel, or a panel saying there is none.

    The image sent to the model, else one `renderer` draws for the video (labelled as such).
    """
    # deferred: OpenCV (about 0.13 s) and numpy load only when a video is made
    import cv2
    import numpy as np

    panel = np.full((PANEL_H, PANEL_W, 3), 235, np.uint8)
    path = view.image_files.get(step.image) if step is not None and step.image else None
    image = None
    rendered = False
    if path is not None:  # the same checks as the page's images: a regular file in the run, a picture
        try:
            data = read_bytes(path, limit=IMAGE_LIMIT, root=view.run_dir)
        except (OSError, UnsafeFileError):
            data = b""
        if image_kind(data) is not None:
            image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    if image is None and step is not None and not step.image and renderer is not None:
        image = renderer.render(step.pose_before or step.pose_after)
        rendered = image is not None
    if image is None:
        text = "no camera image sent" if step is None or not step.image else "camera image missing"
        cv2.putText(panel, text, (170, PANEL_H // 2), cv2.FONT_HERSHEY_SIMPLEX, 0.8, (90, 90, 90), 2, cv2.LINE_AA)
        return panel
    scale = min(PANEL_W / image.shape[1], PANEL_H / image.shape[0])
    w, h = max(1, int(image.shape[1] * scale)), max(1, int(image.shape[0] * scale))
    resized = cv2.resize(image, (w, h))
    top, left = (PANEL_H - h) // 2, (PANEL_W - w) // 2
    panel[top : top + h, left : left + w] = resized
    label = "camera view rendered for the video (the model was not sent it)" if rendered else "camera image sent"
    cv2.rectangle(panel, (0, 0), (PANEL_W, 26), (255, 255, 255), -1)
    cv2.putText(panel, label, (8, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (60, 60, 60), 1, cv2.LINE_AA)
    return panel


def _ascii(text: str) -> str:
    """OpenCV's fonts draw ASCII only: replace the rest (model text may hold anything)."""
    swaps = {"°": " deg", "—": "-", "–": "-", "…": "...", "×": "x", "→": "->", "ω": "w"}
    for old, new in swaps.items():
        text = text.replace(old, new)
    return "".join(ch if 32 <= ord(ch) < 127 else "?" for ch in text)


def _caption(step: StepView | None, total: int) -> list[str]:
    if step is None:
        return ["no decision was logged", ""]
    first = f"{step.label} of {total}: {step.action_text}"
    second = f"reasoning: {step.reasoning}" if step.reasoning else ""
    return [_ascii(first)[:110], _ascii(second)[:110]]


def _segments(view: RunView) -> list[tuple[StepView | None, list[list[float]]]]:
    """Per decision, the trajectory samples from it to the next decision (by simulation time)."""
    timed: list[tuple[float | None, list[float]]] = []  # (sim time, pose) of every trajectory sample
    for event in view.record.events:
        pose = as_pose(event.get("pose")) if event.get("type") == "pose" else None
        if pose is not None:
            stamp = event.get("t_sim")
            timed.append((float(stamp) if isinstance(stamp, (int, float)) else None, pose))
    steps = view.steps
    if not steps:
        return [(None, [pose for _, pose in timed])]
    out: list[tuple[StepView | None, list[list[float]]]] = []
    for i, step in enumerate(steps):
        start = step.t_sim
        end = steps[i + 1].t_sim if i + 1 < len(steps) else math.inf
        inside: list[list[float]] = []
        if isinstance(start, (int, float)) and isinstance(end, (int, float)):
            inside = [pose for stamp, pose in timed if stamp is not None and start <= stamp < end]
        if not inside:  # no timed samples: straight from the pose before to the pose after
            inside = [p for p in (step.pose_before, step.pose_after) if isinstance(p, list) and len(p) >= 3]
        out.append((step, inside))
    return out


def _frames(view: RunView, fps: float, seconds_per_step: float, render_camera: bool = True) -> Iterator[np.ndarray]:
    base = draw_base_map(
        view.scenario,
        PANEL_W,
        PANEL_H,
        oracle=view.oracle,
        trajectory=view.trajectory,
        faint_paths=True,
        targets=view.targets,
        radius_m=view.success_radius_m,
    )
    per_action = max(1, round(fps * seconds_per_step))
    segments = _segments(view)
    renderer = CameraRenderer(view) if render_camera else None
    try:
        yield from _compose(view, base, segments, per_action, fps, renderer)
    finally:
        if renderer is not None:
            renderer.close()


def _compose(
    view: RunView,
    base: Any,
    segments: list[tuple[StepView | None, list[list[float]]]],
    per_action: int,
    fps: float,
    renderer: CameraRenderer | None,
) -> Iterator[np.ndarray]:
    # deferred: OpenCV (about 0.13 s) and numpy load only when a video is made
    import cv2
    import numpy as np

    trail: list[tuple[int, int]] = []
    number = 0  # frames so far; its clock in the corner also keeps every frame distinct (GIF writers merge twins)
    last_pose: list[float] | None = view.trajectory[0] if view.trajectory else None
    for step, samples in segments:
        camera = _camera(view, step, renderer)
        lines = _caption(step, len(view.steps))
        per_step = per_action * _actions(step)
        for k in range(per_step):
            if samples:
                pose = samples[min(len(samples) - 1, (k * len(samples)) // per_step)]
                last_pose = pose
            else:
                pose = last_pose  # type: ignore[assignment]
            top = base.pixels.copy()
            if pose is not None and len(pose) >= 2:
                cx, cy = base.to_px(float(pose[0]), float(pose[1]))
                if not trail or trail[-1] != (cx, cy):
                    trail.append((cx, cy))
                if len(trail) > 1:
                    cv2.polylines(top, [np.array(trail, np.int32)], False, (176, 108, 43), 2, cv2.LINE_AA)
                cv2.circle(top, (cx, cy), ROBOT_PX, (140, 63, 213), -1, cv2.LINE_AA)
                yaw = float(pose[2]) if len(pose) > 2 else 0.0
                tip = (round(cx + 2.2 * ROBOT_PX * math.cos(yaw)), round(cy - 2.2 * ROBOT_PX * math.sin(yaw)))
                cv2.line(top, (cx, cy), tip, (20, 20, 20), 2, cv2.LINE_AA)
            frame = np.full((PANEL_H + CAPTION_H, 2 * PANEL_W, 3), 255, np.uint8)
            frame[:PANEL_H, :PANEL_W] = top
            frame[:PANEL_H, PANEL_W:] = camera
            clock = f"{number / fps:7.2f} s"
            cv2.putText(
                frame,
                clock,
                (2 * PANEL_W - 110, PANEL_H + 28),
                cv2.FONT_HERSHEY_SIMPLEX,
                0.6,
                (90, 90, 90),
                1,
                cv2.LINE_AA,
            )
            number += 1
            for row, text in enumerate(lines):
                cv2.putText(
                    frame,
                    text,
                    (12, PANEL_H + 28 + 30 * row),
                    cv2.FONT_HERSHEY_SIMPLEX,
                    0.62,
                    (25, 25, 25),
                    1,
                    cv2.LINE_AA,
                )
            yield frame


def _actions(step: StepView | None) -> int:
    """How many `seconds_per_step` slots a decision gets: one per executed action, at least one."""
    return max(1, len(step.actions)) if step is not None else 1


def writable_codec(probe_dir: Path) -> str | None:
    """The first of `CODECS` this OpenCV build can write to an .mp4 here (None: none can)."""
    # deferred: OpenCV (about 0.13 s) loads only when a video is made
    import cv2

    # A codec without an encoder makes FFmpeg and OpenCV print several error lines: quiet while probing.
    saved_env = os.environ.get(_FFMPEG_LOG_ENV)
    saved_level = cv2.utils.logging.getLogLevel()
    os.environ[_FFMPEG_LOG_ENV] = "-8"  # AV_LOG_QUIET
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)
    try:
        for codec in CODECS:
            path = probe_dir / f".codec-probe-{codec}.mp4"
            writer = cv2.VideoWriter(str(path), cv2.VideoWriter.fourcc(*codec), 10.0, (64, 48))
            try:
                if writer.isOpened():
                    return codec
            finally:
                writer.release()
                path.unlink(missing_ok=True)
        return None
    finally:
        cv2.utils.logging.setLogLevel(saved_level)
        if saved_env is None:
            os.environ.pop(_FFMPEG_LOG_ENV, None)
        else:
            os.environ[_FFMPEG_LOG_ENV] = saved_env


MAX_FPS = 60.0  # frames per second: more is no smoother on any screen, only larger
# frames per second: slower is a slide show (--seconds-per-step slows the story), and a GIF's frame delay
# is a 16-bit count of centiseconds, which --fps 0.001 overflowed
MIN_FPS = 1.0
MAX_SECONDS_PER_STEP = 60.0  # [s] of video per action
MAX_FRAMES = 36_000  # one hour at 10 fps; every frame is drawn and encoded


def check_timing(fps: float, seconds_per_step: float) -> None:
    """Refuse --fps outside [MIN_FPS, MAX_FPS], --seconds-per-step outside (0, its maximum], NaN and infinity."""
    if not (math.isfinite(fps) and MIN_FPS <= fps <= MAX_FPS):
        raise BadInputError(f"--fps {fps:g}: give a number from {MIN_FPS:g} to {MAX_FPS:g}")
    if not (math.isfinite(seconds_per_step) and 0 < seconds_per_step <= MAX_SECONDS_PER_STEP):
        raise BadInputError(
            f"--seconds-per-step {seconds_per_step:g}: give a number above 0 and at most {MAX_SECONDS_PER_STEP:g}"
        )


def frame_count(view: RunView, fps: float, seconds_per_step: float) -> int:
    """How many frames `_frames` draws: `per_action` for every action slot of every decision."""
    per_action = max(1, round(fps * seconds_per_step))
    return sum(per_action * _actions(step) for step, _ in _segments(view))


def render_video(
    view: RunView, out: Path, *, fps: float = 10.0, seconds_per_step: float = 1.0, render_camera: bool = True
) -> VideoInfo:
    """Write the episode to `out` (.mp4 or .gif); returns what was written.

    `render_camera`: decisions that sent the model no image show the camera's view rendered for the video.
    """
    suffix = out.suffix.lower()
    if suffix not in (".mp4", ".gif"):
        raise BadInputError(f"--video {out}: give a file ending in .mp4 or .gif")
    check_timing(fps, seconds_per_step)
    frames = frame_count(view, fps, seconds_per_step)
    if frames > MAX_FRAMES:
        raise BadInputError(
            f"--video: {frames:,} frames at --fps {fps:g} and --seconds-per-step {seconds_per_step:g}, over the "
            f"limit of {MAX_FRAMES:,}; lower either"
        )
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise BadInputError(f"--video {out}: cannot create its folder: {err.strerror or err}") from None

    width, height = 2 * PANEL_W, PANEL_H + CAPTION_H
    # OpenCV and Pillow write to a path: a folder only this process can enter holds the partial file (a
    # link planted under its name cannot be), and the rename replaces whatever is at `out`, never writing
    # through a link there.
    try:
        with private_dir(out.parent) as work:
            codec = writable_codec(work) if suffix == ".mp4" else None
            if suffix == ".mp4" and codec is None:  # the GIF fallback: this OpenCV build encodes no MP4 codec
                out = out.with_suffix(".gif")
            tmp = work / ("partial" + out.suffix)
            if codec is None:
                info = _write_gif(view, tmp, fps, seconds_per_step, width, height, render_camera)
            else:
                info = _write_mp4(view, tmp, codec, fps, seconds_per_step, width, height, render_camera)
            os.replace(tmp, out)
    except OSError as err:
        raise BadInputError(f"--video {out}: cannot write: {err.strerror or err}") from None
    info.path = out
    return info


def _write_mp4(
    view: RunView, tmp: Path, codec: str, fps: float, sps: float, width: int, height: int, render_camera: bool
) -> VideoInfo:
    # deferred: OpenCV (about 0.13 s) loads only when a video is made
    import cv2

    writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter.fourcc(*codec), fps, (width, height))
    frames = 0
    try:
        for frame in _frames(view, fps, sps, render_camera):
            writer.write(frame)
            frames += 1
    finally:
        writer.release()
    return VideoInfo(tmp, frames, fps, codec, width, height)


def _write_gif(
    view: RunView, tmp: Path, fps: float, sps: float, width: int, height: int, render_camera: bool
) -> VideoInfo:
    # deferred: OpenCV (about 0.13 s) and Pillow load only when a GIF is made
    import cv2
    from PIL import Image

    size = (round(width * GIF_SCALE), round(height * GIF_SCALE))
    images: list[Any] = []
    for frame in _frames(view, fps, sps, render_camera):
        small = cv2.resize(frame, size, interpolation=cv2.INTER_AREA)
        images.append(Image.fromarray(cv2.cvtColor(small, cv2.COLOR_BGR2RGB)).quantize(colors=128))
    # GIF delays are whole centiseconds: fps values that do not divide 100 are rounded to the nearest.
    delay_ms = 10 * round(100 / fps)
    images[0].save(tmp, save_all=True, append_images=images[1:], duration=delay_ms, loop=0, optimize=False, disposal=1)
    return VideoInfo(tmp, len(images), 1000 / delay_ms, "gif", *size)
