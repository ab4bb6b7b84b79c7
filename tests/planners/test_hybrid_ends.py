"""Honest ends of the hybrid planner: an option that moves the robot nowhere leaves the menu, and a task
nothing reachable fits ends `not_found` instead of a Finish somewhere wrong."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

from llmnav.planners.base import drive_options
from llmnav.runs.runlog import read_run
from llmnav.runs.runner import EpisodeSpec, run_episode

PEN = Path(__file__).parent / "data" / "pen.yaml"


def test_a_target_seen_but_walled_in_leaves_the_menu_and_the_episode_ends_not_found(tmp_path: Path) -> None:
    spec = EpisodeSpec(
        scenario=str(PEN),
        task_id="P1",
        options=drive_options(planner="hybrid", max_iterations=30),
        backend="policy:oracle",  # every answer right: the crate is the target, and it cannot be reached
        out_dir=tmp_path / "pen",
    )
    summary = run_episode(spec)
    record = read_run(tmp_path / "pen")
    assert summary["outcome"] == "not_found", summary.get("reason")
    assert not summary["success"] and summary["iterations"] < 30
    dropped = [e for e in record.of_type("planner") if e.get("kind") == "option_dropped"]
    assert dropped and "crate" in dropped[0]["option"] and "no collision-free path" in dropped[0]["reason"]
    # The robot tried the crate from all sides (each leg refused by the low pen wall, mapped, detoured),
    # then the trip left the menu: nothing after it goes for the crate again.
    later = [a.get("option") or "" for a in record.of_type("action") if a["step"] > dropped[0]["step"]]
    assert later and not any("crate" in text for text in later)
    assert summary.get("collisions", 0) == 0
    assert not any(a.get("command") == "COMPLETE" for a in record.of_type("action"))


def test_at_an_explored_edge_the_robot_looks_around_so_a_mapped_room_is_also_seen(tmp_path: Path) -> None:
    """Generated flat 1, "Go to the fridge" from start 1, every answer right. The LiDAR maps the kitchen
    from its doorway, so no frontier is left there; the camera saw it only on arriving at an explored edge
    and turning round (without the turn the episode ended `not_found`, 1.8 m from the fridge)."""
    from llmnav.buildings.generate import Request, generate

    flat = tmp_path / "flat-1.yaml"
    flat.write_text(generate(Request("flat", 1)).text)
    spec = EpisodeSpec(
        scenario=str(flat),
        task_id="T1",
        options=drive_options(planner="hybrid", information="sensed"),
        backend="policy:oracle",
        out_dir=tmp_path / "run",
        plots=False,
    )
    summary = run_episode(spec)
    assert summary["task_text"] == "Go to the fridge"
    assert summary["success"], summary["reason"]
    record = read_run(tmp_path / "run")
    # it found the fridge by exploring (from the start it is out of sight)
    assert any(str(a.get("option", "")).startswith("Explore") for a in record.of_type("action"))


def test_a_frontier_with_no_path_returns_after_the_next_exploration(monkeypatch: Any) -> None:
    """A frontier that had no path leaves the menu only until a frontier is explored (the map grows, and a
    doorway whose floor was unknown may then have one); one reached before stays off for good."""
    from llmnav.core.geometry import Pose2D
    from llmnav.planners.hybrid import menu, planner
    from llmnav.planners.hybrid.config import HybridConfig
    from llmnav.planners.hybrid.memory import Memory

    pose = Pose2D(0.0, 0.0, 0.0)
    events: list[dict[str, Any]] = []
    ctx = SimpleNamespace(
        information="oracle",
        world=SimpleNamespace(robot=SimpleNamespace(pose=lambda: pose), sim_time=0.0),
        log=SimpleNamespace(sim_time=0.0, event=lambda _type, **fields: events.append(fields)),
        scenario=SimpleNamespace(corridors=[]),
        options=SimpleNamespace(explore="utility"),
    )
    memory = Memory()
    doorway, hall = (4.0, 0.0), (0.0, 5.0)
    monkeypatch.setattr(menu, "frontier_points", lambda inputs: [(doorway, 2.0), (hall, 2.0)])
    inputs = SimpleNamespace(ctx=ctx, cfg=HybridConfig(), memory=memory, pose=pose)

    def offered() -> set[tuple[float, float]]:
        return {o.goal for o in menu.frontier_options(inputs)}  # type: ignore[arg-type,misc]

    assert offered() == {doorway, hall}
    option = menu.Option(0, "frontier", "Explore, 4 m ahead", goal=doorway)
    planner._drop_if_stuck(ctx, memory, option, pose, "no collision-free path (the explored edge)", 3)  # type: ignore[arg-type]
    assert offered() == {hall} and events and events[0]["kind"] == "option_dropped"
    memory.reached_frontier(hall)
    assert offered() == {doorway}
