"""`llmnav view` of a Gymnasium episode written by `llmnav.gym.RunLog`: every action named as the agent took it."""

from __future__ import annotations

import html
import re
from pathlib import Path

import numpy as np

from llmnav.gym import FactoryEnv, RunLog
from llmnav.view.api import write_view
from llmnav.view.model import build_run_view

SMALL = str(Path(__file__).parents[1] / "runner" / "small_room.yaml")


def _action(command: str, distance_m: float = 0.0, angle_deg: float = 0.0) -> dict:
    return {
        "command": FactoryEnv.COMMANDS.index(command),
        "distance_m": np.array([distance_m], dtype=np.float32),
        "angle_deg": np.array([angle_deg], dtype=np.float32),
    }


def test_view_of_a_gym_episode(tmp_path: Path) -> None:
    env = RunLog(FactoryEnv(scenario=SMALL, task_id="T1"), tmp_path / "gym", agent="scripted")
    env.reset(seed=0)
    for action in (_action("ROTATE_LEFT", angle_deg=30.0), _action("BACK", 0.5), _action("COMPLETE")):
        if env.step(action)[2]:
            break
    env.close()
    run_dir = tmp_path / "gym" / "episode-0001"
    view = build_run_view(run_dir)
    texts = [step.action_text for step in view.steps]
    assert len(texts) == 3, texts  # one decision per action: no empty "step 0" before them
    assert texts[0].startswith("ROTATE_LEFT") and texts[1].startswith("BACK 0.5") and texts[2] == "COMPLETE"
    assert all(step.image for step in view.steps)  # each decision shows the reading it was taken from
    page = html.unescape(write_view(run_dir, tmp_path / "gym.html").page.read_text(encoding="utf-8"))
    assert "no action" not in page and "? None" not in page
    assert re.search(r"BACK 0\.5\d* m", page) and "COMPLETE" in page
