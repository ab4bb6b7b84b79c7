"""Cross-cutting behaviour of llmnav's environments as Gymnasium wrappers.

- `SafetyVeto`: the swept-corridor LiDAR veto llmnav's planners get, applied to every action before it
  moves the robot. `gymnasium.make` adds it; build the environment with `safety_veto=False` to drop it.
- `RunLog`: writes llmnav's run folder (`run.jsonl`, `summary.json`, the images) per episode, so
  `llmnav score` (and the run viewer) read any agent's episodes like a planner's.
- `TextObservation`: the observation as the text llmnav sends a model (task, LiDAR sectors, detections).

Each wrapper reads the environment's last raw readings (`env.unwrapped.last_scan`, `last_detections`):
the veto judges the scan the agent was shown, never a number the agent supplied.
"""

from __future__ import annotations

import hashlib
import string
from pathlib import Path
from typing import TYPE_CHECKING, Any, SupportsFloat

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from llmnav.errors import BadInputError
from llmnav.guard.veto import check_motion
from llmnav.perception import detections_text, summarize_scan

if TYPE_CHECKING:
    from llmnav.gym.env import NavEnv
    from llmnav.runlog import RunLog as RunLogWriter

VETO_MARGIN_M = 0.15  # [m] lateral margin of the swept corridor (the stepwise planner's default)
VETO_STOP_MARGIN_M = 0.2  # [m] how far short of an obstacle a move must end
VELOCITY_HORIZON_S = 1.0  # [s] a velocity command must be collision-free for this long (time to collision)
TEXT_CHARSET = frozenset(string.printable) | {"°"}
MAX_TEXT_CHARS = 8192

Step = tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]


def _base(env: gym.Env[Any, Any]) -> NavEnv:
    from llmnav.gym.env import NavEnv

    base = env.unwrapped
    if not isinstance(base, NavEnv):
        raise BadInputError(f"{type(base).__name__} is not an llmnav environment")
    return base


class SafetyVeto(gym.Wrapper[dict[str, Any], Any, dict[str, Any], Any]):
    """Refuse any action whose straight motion would enter the LiDAR's obstacles.

    A discrete FRONT/BACK of d metres is checked as the robot's footprint (its width plus `margin_m` a
    side) swept d metres ahead or behind, ending `stop_margin_m` short of anything; a velocity command
    (v, w) is checked as the corridor it sweeps in `horizon_s` at speed v (a time-to-collision test).
    Rotations in place are never checked (a round base sweeps no new area). A refused action is not
    executed: the robot stands still for that step, `info["vetoed"]` gives the reason and
    `info["vetoes"]` counts refusals this episode.
    """

    def __init__(
        self,
        env: gym.Env[dict[str, Any], Any],
        *,
        margin_m: float = VETO_MARGIN_M,
        stop_margin_m: float = VETO_STOP_MARGIN_M,
        horizon_s: float = VELOCITY_HORIZON_S,
    ) -> None:
        super().__init__(env)
        self.margin_m = margin_m
        self.stop_margin_m = stop_margin_m
        self.horizon_s = horizon_s
        self.vetoes = 0

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, Any], dict[str, Any]]:
        """Reset the count of refusals with the episode."""
        self.vetoes = 0
        obs, info = self.env.reset(seed=seed, options=options)
        info["vetoes"] = 0
        return obs, info

    def step(self, action: Any) -> Step:
        """Check the action's straight motion against the current scan; execute it only if clear."""
        base = _base(self.env)
        reason = self.check(action)
        if reason is not None:
            self.vetoes += 1
        result: Step = base.idle_step(reason) if reason is not None else self.env.step(action)
        result[4]["vetoes"] = self.vetoes
        return result

    def check(self, action: Any) -> str | None:
        """Why `action` is refused, or None when it may go ahead."""
        base = _base(self.env)
        distance = base.straight_motion(action, self.horizon_s)
        if distance is None or distance == 0.0:
            return None
        robot = base.spec_robot
        verdict = check_motion(
            distance,
            base.last_scan,
            robot_width_m=robot.width_m,
            robot_radius_m=robot.radius_m,
            margin_m=self.margin_m,
            stop_margin_m=self.stop_margin_m,
        )
        return None if verdict.allowed else verdict.reason


class RunLog(gym.Wrapper[Any, Any, Any, Any]):
    """Write each episode as an llmnav run folder under `out_dir` (`episode-0001`, `episode-0002`, ...).

    The configuration line names the scenario, task, start pose, seed and what the agent knew; each step
    logs its camera image, action, the true-pose trajectory and any veto; the episode's end writes
    `summary.json` with llmnav's metrics (`llmnav.metrics.summarize_run`). An episode left by `reset` or
    `close` before it ended is closed as "aborted". Wrap it outside `SafetyVeto` so vetoes are logged.
    """

    def __init__(
        self,
        env: gym.Env[Any, Any],
        out_dir: str | Path,
        *,
        agent: str = "agent",
        backend: str | None = None,
        images: bool = True,
    ) -> None:
        super().__init__(env)
        self.out_dir = Path(out_dir)
        self.agent = agent
        self.backend = backend
        self.images = images
        self.episodes = 0
        self.run_dir: Path | None = None
        self._log: RunLogWriter | None = None
        self._logged_samples = 0
        self._step = 0

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        """End any open episode as aborted, then open the next episode's run folder."""
        self._end("aborted", "reset before the episode ended")
        obs, info = self.env.reset(seed=seed, options=options)
        self._open(seed)
        self._observation(obs)
        return obs, info

    def step(self, action: Any) -> Step:
        """Log the action, its effect and (at the end) the summary."""
        base = _base(self.env)
        before = base.world.robot.pose().as_list()
        obs, reward, terminated, truncated, info = self.env.step(action)
        self._step += 1
        log = self._log
        if log is not None:
            self._poses()
            if info.get("vetoed"):
                log.event("guard", step=self._step, outcome="veto", reason=str(info["vetoed"]))
            log.event(
                "action",
                step=self._step,
                action=base.describe(action),
                vetoed=bool(info.get("vetoed")),
                pose_before=before,
                pose_after=base.world.robot.pose().as_list(),
                collided=bool(info.get("collided_with")),
                reward=round(float(reward), 6),
            )
            self._observation(obs)
            if terminated:
                self._end("completed", "the agent ended the episode")
            elif truncated:
                self._end("failed", f"max_steps ({base.options.max_steps}) reached")
        return obs, reward, terminated, truncated, info

    def close(self) -> None:
        """Close any open episode as aborted, then the environment."""
        self._end("aborted", "closed before the episode ended")
        super().close()

    # --- internals ----------------------------------------------------------------------------------
    def _open(self, seed: int | None) -> None:
        from llmnav import __version__
        from llmnav.runlog import RunLog as RunLogWriter
        from llmnav.runner import task_record
        from llmnav.scenario import resolve_scenario_path

        base = _base(self.env)
        self.episodes += 1
        self.run_dir = self.out_dir / f"episode-{self.episodes:04d}"
        scenario_path = resolve_scenario_path(base.options.scenario)
        start = base.trajectory[0]
        config = {
            "versions": {"llmnav": __version__},
            "scenario": base.scenario.name,
            "scenario_file": str(scenario_path),
            "scenario_hash": hashlib.sha256(scenario_path.read_bytes()).hexdigest()[:16],
            "task": task_record(base.task),
            "start_pose_index": base.start_index,
            "start_pose": start,
            "planner": f"gym:{self.agent}",
            "backend": self.backend,
            "information": base.options.information,
            "options": base.options.model_dump(mode="json"),
            "seed": seed,
            "env": type(base).__name__,
        }
        self._log = RunLogWriter(self.run_dir, config)
        self._log.sim_time = base.world.sim_time
        self._logged_samples = 0
        self._step = 0
        self._poses()

    def _poses(self) -> None:
        """Log the true-pose samples the episode gained since the last call."""
        base = _base(self.env)
        assert self._log is not None
        self._log.sim_time = base.world.sim_time
        for pose in base.trajectory[self._logged_samples :]:
            self._log.event("pose", pose=pose)
        self._logged_samples = len(base.trajectory)

    def _observation(self, obs: Any) -> None:
        """Log the reading the agent was given (the camera from the world when the observation is text)."""
        if self._log is None:
            return
        base = _base(self.env)
        image = None
        if self.images:
            from llmnav.sim.sensors import CameraFrame

            rgb = obs["image"] if isinstance(obs, dict) and "image" in obs else base.world.camera.capture().rgb
            image = self._log.image(CameraFrame(rgb=np.asarray(rgb), segmentation=None).image())
        odom = base.world.robot.odom()
        self._log.event(
            "observation",
            step=self._step,
            odom=[round(odom.x, 4), round(odom.y, 4), round(odom.yaw, 4)],
            text=obs if isinstance(obs, str) else None,
            image=image,
            detections=[{"label": d.label, "distance_m": round(d.distance_m, 3)} for d in base.last_detections],
        )

    def _end(self, outcome: str, reason: str) -> None:
        log = self._log
        if log is None:
            return
        from llmnav.metrics import summarize_run
        from llmnav.runlog import read_run

        base = _base(self.env)
        log.event("end", outcome=outcome, reason=reason, iterations=self._step, metrics={})
        log.close()
        self._log = None
        assert self.run_dir is not None
        summary = summarize_run(read_run(self.run_dir), base.scenario)
        summary["run_dir"] = str(self.run_dir)
        from llmnav.runlog import SUMMARY_FILE, write_json_atomic

        write_json_atomic(self.run_dir / SUMMARY_FILE, summary)


def observation_text(env: gym.Env[Any, Any]) -> str:
    """The last observation as llmnav's model-facing text: task, LiDAR summary, detections."""
    base = _base(env)
    if base.last_scan is None:
        raise BadInputError("no observation yet: call reset() first")
    summary = summarize_scan(base.last_scan, base.options.lidar_sectors, base.options.lidar_fov_deg)
    parts = [f"Task: {base.task.text}", summary.text()]
    if "detections" in base.options.sensing:
        parts.append(detections_text(base.last_detections))
    text = "\n\n".join(parts)
    return "".join(c if c in TEXT_CHARSET else "?" for c in text)[:MAX_TEXT_CHARS]


class TextObservation(gym.ObservationWrapper[str, Any, dict[str, Any]]):
    """Replace the observation with the text llmnav's planners send a model (see `observation_text`)."""

    def __init__(self, env: gym.Env[dict[str, Any], Any]) -> None:
        super().__init__(env)
        self.observation_space = spaces.Text(MAX_TEXT_CHARS, min_length=1, charset=TEXT_CHARSET)

    def observation(self, observation: dict[str, Any]) -> str:
        """The text of the reading the environment just took."""
        return observation_text(self.env)
