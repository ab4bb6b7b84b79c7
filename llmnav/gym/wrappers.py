"""Cross-cutting behaviour of llmnav's environments as Gymnasium wrappers.

- `SafetyVeto`: actions move the robot through llmnav's guarded motion layer (the swept-corridor veto and
  the time-to-collision check every planner gets). `gymnasium.make` adds it; build the environment with
  `safety_veto=False` to drop it.
- `RunLog`: writes llmnav's run folder (`run.jsonl`, `summary.json`, the images) per episode, so
  `llmnav score` (and the run viewer) read any agent's episodes like a planner's.
- `TextObservation`: the observation as the text llmnav sends a model (task, LiDAR sectors, detections).

The layer judges LiDAR scans and the robot's numbers, never anything the agent supplied but the action.
"""

from __future__ import annotations

import hashlib
import string
from pathlib import Path
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from llmnav import __version__
from llmnav.errors import BadInputError
from llmnav.guard.motion import MotionGuardConfig
from llmnav.guard.view import PlannerWorld
from llmnav.gym.env import NavEnv
from llmnav.runs.runlog import SUMMARY_FILE, read_run, write_json_atomic
from llmnav.runs.runlog import RunLog as RunLogWriter
from llmnav.runs.runner import task_record
from llmnav.scoring.metrics import summarize_run
from llmnav.sensing.perception import detections_text, summarize_scan
from llmnav.sim.sensors import CameraFrame
from llmnav.world.scenario import resolve_scenario_path

TEXT_CHARSET = frozenset(string.printable) | {"°"}
MAX_TEXT_CHARS = 8192

Step = tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]


def _base(env: gym.Env[Any, Any]) -> NavEnv:
    base = env.unwrapped
    if not isinstance(base, NavEnv):
        raise BadInputError(f"{type(base).__name__} is not an llmnav environment")
    return base


class SafetyVeto(gym.Wrapper[dict[str, Any], Any, dict[str, Any], Any]):
    """Move the robot only through llmnav's guarded motion layer, the one every planner gets.

    A FRONT/BACK is checked as the robot's footprint swept along the move against the latest LiDAR scan
    and refused when it would reach an obstacle (the robot does not move); a velocity command is clipped
    to the kinematic box and its forward speed set to 0 when the time-to-collision check fails (the turn
    still applies). Rotations in place are never checked (a round base sweeps no new area). Either way
    `info["vetoed"]` gives the reason, `info["vetoes"]` counts the steps of this episode that were
    vetoed (a velocity command overridden on 40 steps in a row counts 40) and `info["guard_events"]`
    holds the layer's `guard`/`override` events of this step.
    """

    def __init__(self, env: gym.Env[dict[str, Any], Any], *, config: MotionGuardConfig | None = None) -> None:
        super().__init__(env)
        self._events: list[dict[str, Any]] = []
        self._vetoed_steps = 0
        base = _base(env)
        self._layer = PlannerWorld(base.world, _EventList(self._events), config)
        base.motion = self._layer.motion

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, Any], dict[str, Any]]:
        """Reset the count of vetoed steps with the episode."""
        self._layer.motion.vetoes = 0
        self._vetoed_steps = 0
        obs, info = self.env.reset(seed=seed, options=options)
        info["vetoes"] = 0
        return obs, info

    def step(self, action: Any) -> Step:
        """Carry out the action through the guarded layer; report what it refused."""
        self._events.clear()
        result: Step = self.env.step(action)
        info = result[4]
        info["guard_events"] = [dict(e) for e in self._events]
        if "vetoed" not in info:
            reasons = [e.get("reason") or e.get("error") for e in self._events]
            if any(reasons):
                info["vetoed"] = next(r for r in reasons if r)
        # Counted per step here: the layer counts a run of overridden velocity ticks once (a planner's
        # view), while a learner's step is the unit its `info` speaks of.
        self._vetoed_steps += "vetoed" in info
        info["vetoes"] = self._vetoed_steps
        return result


class _EventList:
    """An event sink that keeps the guarded layer's events for the step's `info`."""

    def __init__(self, events: list[dict[str, Any]]) -> None:
        self.events = events
        self.sim_time: float | None = None  # set by the layer's timed log; unused here

    def event(self, kind: str, **fields: Any) -> None:
        self.events.append({"type": kind, **fields})


class RunLog(gym.Wrapper[Any, Any, Any, Any]):
    """Write each episode as an llmnav run folder under `out_dir` (`episode-0001`, `episode-0002`, ...).

    The configuration line names the scenario, task, start pose, seed and what the agent knew; each step
    logs its camera image, action, the true-pose trajectory and any veto; the episode's end writes
    `summary.json` with llmnav's metrics (`llmnav.scoring.metrics.summarize_run`). An episode left by `reset` or
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
            for event in info.get("guard_events", []):
                fields = {k: v for k, v in event.items() if k != "type"}
                fields["step"] = self._step
                log.event(str(event["type"]), **fields)
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
            "start_pose_index": base.start_index if base.start_mode == "listed" else None,  # random: no index
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

        base = _base(self.env)
        log.event("end", outcome=outcome, reason=reason, iterations=self._step, metrics={})
        log.close()
        self._log = None
        assert self.run_dir is not None
        summary = summarize_run(read_run(self.run_dir), base.scenario)
        summary["run_dir"] = str(self.run_dir)

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
