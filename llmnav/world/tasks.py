"""Task resolution: turn `--task TEXT` / `--task-id ID` into a scenario and a `Task`.

- `--task-id T3` names a task of the scenario (the factory's T1–T10, ...).
- `--task TEXT` that equals a scenario task's text (case and punctuation ignored) is that task; text that
  equals one of its paraphrases is that task in that wording (`wording` "paraphrase:<k>").
- Other free text becomes an ad-hoc task whose acceptable targets are the labelled objects the text names:
  a room number ("room 101", "101") matches the objects whose names carry that number; otherwise labels,
  aliases and ids are matched as whole words (the longest names win, so "fire extinguisher" beats "fire").
  Text that names nothing becomes an exploration task. Either way its `wording` is "free". The names are
  the objects' labels and aliases (what people call them), never task sentences.
- Without `--scenario`, free text picks the scenario whose objects it names (a room number → the first
  corridor scenario with that room), else `factory`.
- Several `--task` texts form a sequence (for the waypoint planner): one task with id `SEQ` whose text joins
  the legs with `SEQUENCE_JOIN`; `sequence_legs` splits it back into one resolved task per leg.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from llmnav.errors import BadInputError
from llmnav.world.scenario import (
    SEQUENCE_JOIN,
    LabelledObject,
    Scenario,
    StartPose,
    Target,
    Task,
    list_scenarios,
    load_scenario,
)

DEFAULT_SCENARIO = "factory"
ADHOC_ID = "adhoc"
SEQUENCE_ID = "SEQ"
__all__ = ["SEQUENCE_ID", "SEQUENCE_JOIN"]  # SEQUENCE_JOIN is the scenario's: a route's legs join the same way


def _normalise(text: str) -> str:
    """Lower case, separators as spaces, punctuation dropped, single spaces."""
    text = re.sub(r"[_\-/]", " ", text.lower())
    text = re.sub(r"[^\w\s]", " ", text)
    return " ".join(text.split())


def _same_text(a: str, b: str) -> bool:
    return _normalise(a) == _normalise(b)


def _word_pattern(name: str) -> re.Pattern[str]:
    """A whole-word pattern for a name, also accepting a plural 's'/'es'."""
    return re.compile(rf"\b{re.escape(name)}(?:s|es)?\b")


def _room_numbers(text: str) -> list[str]:
    return re.findall(r"\b(\d{3,4})\b", text)


def _numbered_objects(scenario: Scenario, numbers: list[str]) -> list[LabelledObject]:
    """Objects whose label, alias or id carries one of these numbers as a word (room plates)."""
    return [
        obj
        for obj in scenario.objects
        if any(re.search(rf"\b{n}\b", _normalise(name)) for n in numbers for name in obj.names())
    ]


def named_objects(scenario: Scenario, text: str) -> list[LabelledObject]:
    """The labelled objects a free-text task names (see the module docstring for the rules)."""
    norm = _normalise(text)
    by_number = _numbered_objects(scenario, _room_numbers(norm))
    if by_number:
        return by_number
    best: dict[str, int] = {}
    for obj in scenario.objects:
        lengths = [len(n) for n in map(_normalise, obj.names()) if n and _word_pattern(n).search(norm)]
        if lengths:
            best[obj.id] = max(lengths)
    if not best:
        return []
    longest = max(best.values())
    return [obj for obj in scenario.objects if best.get(obj.id) == longest]


def names_in_text(names: list[str], text: str) -> bool:
    """Whether any of these object names occurs in the text as whole words (plural 's'/'es' accepted)."""
    norm = _normalise(text)
    return any(n and _word_pattern(n).search(norm) for n in map(_normalise, names))


def adhoc_task(scenario: Scenario, text: str) -> Task:
    """A task for free text: targets the named objects, or explores when it names none."""
    objects = named_objects(scenario, text)
    if not objects:
        return Task(id=ADHOC_ID, text=text, kind="explore", difficulty="medium", wording="free")
    targets = [Target(object=o.id) for o in objects]
    return Task(id=ADHOC_ID, text=text, kind="target", targets=targets, wording="free")


def task_wordings(task: Task) -> list[str]:
    """The wordings a task can be run in: "bundled", then "paraphrase:1" ... one per paraphrase."""
    return ["bundled", *(f"paraphrase:{k}" for k in range(1, len(task.paraphrases) + 1))]


def in_wording(task: Task, wording: str) -> Task:
    """The task worded as asked (same id, targets and start poses); bad input names the wordings there are."""
    if wording == "bundled":
        return task
    prefix, _, number = wording.partition(":")
    if prefix == "paraphrase" and number.isdigit() and 1 <= int(number) <= len(task.paraphrases):
        return task.model_copy(update={"text": task.paraphrases[int(number) - 1], "wording": wording})
    known = ", ".join(task_wordings(task))
    raise BadInputError(f"task '{task.id}' has no wording '{wording}' (wordings: {known})")


def worded_text(scenario_name: str, task_id: str, wording: str) -> str | None:
    """The text that runs a scenario task in a wording (None for "bundled": run it by id).

    The hook of the paraphrase factor (`llmnav ablate --paraphrases`): the runner resolves the text back
    to the same task, in that wording.
    """
    if wording == "bundled":
        return None
    return in_wording(task_from_id(load_scenario(scenario_name), task_id), wording).text


def task_from_text(scenario: Scenario, text: str) -> Task:
    """The scenario task with exactly this text or one of its paraphrases, else an ad-hoc task."""
    for task in scenario.tasks:
        if _same_text(task.text, text):
            return task
        for k, paraphrase in enumerate(task.paraphrases, start=1):
            if _same_text(paraphrase, text):
                return in_wording(task, f"paraphrase:{k}")
    return adhoc_task(scenario, text)


def task_from_id(scenario: Scenario, task_id: str) -> Task:
    """A scenario task by id; a one-line error lists the known ids."""
    try:
        return scenario.task(task_id)
    except KeyError:
        known = ", ".join(t.id for t in scenario.tasks) or "none"
        raise BadInputError(f"scenario '{scenario.name}' has no task '{task_id}' (tasks: {known})") from None


def _scenario_order() -> list[str]:
    """Bundled scenarios, the default first."""
    names = list_scenarios()
    return sorted(names, key=lambda n: (n != DEFAULT_SCENARIO, n))


def default_scenario(texts: list[str] | None, task_id: str | None) -> str:
    """The scenario to use when none is given (rules in the module docstring)."""
    names = _scenario_order()
    if task_id is not None:
        for name in names:
            if any(t.id.lower() == task_id.lower() for t in load_scenario(name).tasks):
                return name
        return DEFAULT_SCENARIO
    text = " ".join(texts or [])
    for name in names:  # an exact task text (or paraphrase) wins
        tasks = load_scenario(name).tasks
        if any(_same_text(w, leg) for t in tasks for w in (t.text, *t.paraphrases) for leg in texts or []):
            return name
    numbers = _room_numbers(_normalise(text))
    if numbers:
        corridors = sorted(n for n in names if n.startswith("corridor"))
        for name in corridors + [n for n in names if n not in corridors]:
            if _numbered_objects(load_scenario(name), numbers):
                return name
    for name in names:
        if named_objects(load_scenario(name), text):
            return name
    return DEFAULT_SCENARIO


def sequence_task(scenario: Scenario, legs: list[Task]) -> Task:
    """One task for a sequence of legs; the final leg's targets are the episode's targets."""
    last = legs[-1]
    return Task(
        id=SEQUENCE_ID,
        text=SEQUENCE_JOIN.join(leg.text for leg in legs),
        kind=last.kind,
        difficulty=max((leg.difficulty for leg in legs), key=["easy", "medium", "hard"].index),
        targets=list(last.targets),
        start_poses=list(legs[0].start_poses),
    )


def sequence_legs(scenario: Scenario, task: Task) -> list[Task]:
    """The legs of a task: a route's legs (`Route`), each leg of a `SEQ` task resolved again, or itself.

    A route's leg k is task `<route id>.<k>` with the leg's own targets (the scenario's ground truth, never
    re-read from its text).
    """
    if task.legs:
        return [
            Task(
                id=f"{task.id}.{k}", text=leg.text, kind="target", difficulty=task.difficulty, targets=list(leg.targets)
            )  # fmt: skip
            for k, leg in enumerate(task.legs, start=1)
        ]
    if task.id != SEQUENCE_ID:
        return [task]
    return [task_from_text(scenario, leg) for leg in task.text.split(SEQUENCE_JOIN)]


@dataclass(frozen=True)
class ResolvedTask:
    """A scenario, the task on it, and the start pose chosen."""

    scenario: Scenario
    task: Task
    start_pose_index: int  # 1-based
    start: StartPose


def resolve_task(
    scenario_name: str | None,
    texts: list[str] | None,
    task_id: str | None,
    start_pose: int = 1,
) -> ResolvedTask:
    """Resolve the drive flags into scenario, task and start pose; bad input raises BadInputError."""
    texts = [t for t in (texts or []) if t.strip()]
    if bool(texts) == (task_id is not None):
        raise BadInputError("give exactly one of --task TEXT (repeatable) or --task-id ID")
    scenario = load_scenario(scenario_name or default_scenario(texts, task_id))
    if task_id is not None:
        task = task_from_id(scenario, task_id)
    elif len(texts) == 1:
        task = task_from_text(scenario, texts[0])
    else:
        task = sequence_task(scenario, [task_from_text(scenario, t) for t in texts])
    poses = scenario.start_poses(task)
    if not 1 <= start_pose <= len(poses):
        raise BadInputError(f"--start-pose {start_pose}: task '{task.id}' has start poses 1..{len(poses)}")
    return ResolvedTask(scenario, task, start_pose, poses[start_pose - 1])
