"""Runs for the view tests, made once per session with scripted replies (no model): a stepwise run with a
hostile reply, a hybrid run, an FSM run with LLM assist, a waypoint run with a replan, a killed run (a
stepwise log cut mid-step, as a SIGKILL leaves it) and a small ablation."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from llmnav.backends.replay import ReplayBackend, write_script
from llmnav.planners.base import DriveOptions, drive_options
from llmnav.runs.runner import EpisodeSpec, run_episode

SMALL = str(Path(__file__).parents[1] / "runner" / "small_room.yaml")
HOSTILE = "</script><script>alert(1)</script><img src=x onerror=alert(2)>"


def step_answer(command: str, parameters: float, reasoning: str) -> str:
    body = {
        "goal": "reach the box",
        "reasoning": reasoning,
        "scene_description": "a room",
        "action": {"command": command, "parameters": parameters},
    }
    return f"```json\n{json.dumps(body)}\n```"


def _drive(root: Path, name: str, replies: list, scenario: str, **spec: object) -> Path:
    purpose = str(spec.pop("purpose", "action"))
    backend = ReplayBackend(write_script(root / f"{name}-script", replies, purpose=purpose, latency_s=0.2))
    options = spec.pop("options")
    assert isinstance(options, DriveOptions)
    run_episode(
        EpisodeSpec(scenario=scenario, options=options, backend=backend.spec, out_dir=root / name, **spec),  # type: ignore[arg-type]
        backend_obj=backend,
    )
    return root / name


@pytest.fixture(scope="session")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("view-runs")
    out: dict[str, Path] = {}
    out["stepwise"] = _drive(
        root,
        "stepwise",
        [
            step_answer("ROTATE_LEFT", 30, f"look left {HOSTILE}"),
            "no JSON here, sorry " + HOSTILE,
            step_answer("FRONT", 1.0, "drive ahead"),
            step_answer("ROTATE_RIGHT", 45, "turn back"),
            step_answer("COMPLETE", 0, "done here"),
        ],
        SMALL,
        task_id="T1",
        options=drive_options(planner="stepwise", sensing=("lidar", "image"), image_width=320, image_height=240),
    )
    out["hybrid"] = _drive(
        root,
        "hybrid",
        [
            "I pick the first one",
            json.dumps({"option": 1, "reasoning": "room 101 is listed first"}),
            json.dumps({"option": 1, "reasoning": "I am there, finish"}),
        ],
        "corridor_a",
        purpose="choice",
        task_text="Go to room 101",
        options=drive_options(planner="hybrid", sensing=("lidar",)),
    )
    mixed = [  # the FSM's answer: [v mm/s, w mrad/s]
        "[50,100]",
        "I would slow down a little.",
        "[2000,0]",
    ] * 4
    out["fsm"] = _drive(
        root,
        "fsm",
        [(text, 0.1) for text in mixed],
        "maze_arena",
        purpose="suggestion",
        task_id="M1",
        options=drive_options(planner="fsm", assist="llm", max_ticks=1500),
    )
    room_105 = (6.5, 1.1)
    straight = json.dumps([{"x": 5.0, "y": 0.0}, {"x": room_105[0], "y": room_105[1]}])
    detour = json.dumps([{"x": 2.6, "y": 1.2}, {"x": 4.5, "y": 1.2}, {"x": room_105[0], "y": room_105[1]}])
    bad = json.dumps([{"x": 3.0, "y": 1.7}, {"x": 6.5, "y": 0.5}])
    out["waypoints"] = _drive(
        root,
        "waypoints",
        [bad, straight, straight, detour],
        "corridor_a",
        purpose="waypoints",
        task_text="Go to room 105",
        options=drive_options(planner="waypoints", obstacles=((3.5, 0.0),)),
    )
    # A killed run: the stepwise log cut inside its third step, the last line torn, no summary.
    killed = root / "killed"
    shutil.copytree(out["stepwise"], killed, ignore=shutil.ignore_patterns("summary.json", "*.png", "view.html"))
    lines = (killed / "run.jsonl").read_text(encoding="utf-8").splitlines()
    third = next(i for i, line in enumerate(lines) if json.loads(line).get("step") == 3)
    cut = lines[: third + 2]
    (killed / "run.jsonl").write_text("\n".join(cut) + "\n" + lines[third + 2][:25], encoding="utf-8")
    out["killed"] = killed
    return out


@pytest.fixture(scope="session")
def sweep(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Four oracle episodes: two start poses × two (irrelevant to the oracle) LiDAR sector counts."""
    from llmnav import ablate

    root = tmp_path_factory.mktemp("view-sweep") / "sweep"
    grid = ablate.GridSpec(scenario=SMALL, tasks=["T1"], poses=[1, 2], planner=["oracle"], lidar_sectors=[3, 8])
    ablate.run(ablate.plan(grid, root))
    return root
