"""Facts read straight from a run log's JSON lines, independently of llmnav's readers (test oracles)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any


def events(run_dir: Path) -> list[dict[str, Any]]:
    out = []
    for line in (run_dir / "run.jsonl").read_text(encoding="utf-8").splitlines():
        try:
            out.append(json.loads(line))
        except json.JSONDecodeError:  # the torn last line of a killed run
            continue
    return out


def decisions(run_dir: Path) -> list[Any]:
    """Decision keys in order: logged step values; for the FSM, one per model call."""
    evs = events(run_dir)
    if evs[0].get("planner") == "fsm":
        return [i for i, e in enumerate(e for e in evs if e["type"] == "llm_call")]
    seen: list[Any] = []
    for e in evs:
        if e["type"] in ("observation", "llm_call", "guard", "action", "planner") and e.get("step") is not None:
            if e["step"] not in seen:
                seen.append(e["step"])
    return seen


def last_reply(run_dir: Path, step: Any) -> str | None:
    """The last reply text logged for a decision."""
    evs = events(run_dir)
    calls = [e for e in evs if e["type"] == "llm_call" and "reply" in e]
    if evs[0].get("planner") == "fsm":
        return calls[step]["reply"]["text"] if step < len(calls) else None
    mine = [c for c in calls if c.get("step") == step]
    return mine[-1]["reply"]["text"] if mine else None


def video_slots(run_dir: Path) -> int:
    """Seconds-per-step slots of a run's video: per decision, its logged actions (at least one)."""
    evs = events(run_dir)
    if evs[0].get("planner") == "fsm":
        return max(1, len(decisions(run_dir)))
    actions = [e.get("step") for e in evs if e["type"] == "action"]
    return sum(max(1, actions.count(key)) for key in decisions(run_dir)) or 1
