"""Task wordings: every bundled task has paraphrases, aliases hold no task sentence, paraphrased and free
text resolve to the right task and wording, and the ablation's wording factor runs them."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from llmnav.ablate import GridSpec, expand
from llmnav.errors import BadInputError
from llmnav.world.scenario import list_scenarios, load_scenario
from llmnav.world.tasks import in_wording, resolve_task, task_from_text, task_wordings

# The phrases the factory's aliases used to hold: the papers' own task wording.
TASK_SENTENCES = ("pile of pellets", "pile of dark brown boxes", "red cylindrical fire extinguisher", "red box")


def _words(text: str) -> str:
    return " ".join(re.sub(r"[^\w\s]", " ", text.lower()).split())


@pytest.mark.parametrize("name", list_scenarios())
def test_every_bundled_task_has_three_distinct_paraphrases(name: str) -> None:
    scenario = load_scenario(name)
    assert scenario.tasks
    for task in scenario.tasks:
        assert len(task.paraphrases) >= 3, task.id
        assert len({_words(t) for t in (task.text, *task.paraphrases)}) == 1 + len(task.paraphrases)


@pytest.mark.parametrize("name", list_scenarios())
def test_no_alias_is_a_task_phrase(name: str) -> None:
    scenario = load_scenario(name)
    wordings = [_words(t) for task in scenario.tasks for t in (task.text, *task.paraphrases)]
    for obj in scenario.objects:
        for alias in map(_words, obj.aliases):
            assert alias not in TASK_SENTENCES, (obj.id, alias)
            # an alias of three or more words that a task says verbatim is the task's answer, not a name
            if len(alias.split()) >= 3:
                assert not any(f" {alias} " in f" {w} " for w in wordings), (obj.id, alias)


def test_paraphrase_text_resolves_to_its_task_in_that_wording() -> None:
    factory = load_scenario("factory")
    t9 = factory.task("T9")
    task = task_from_text(factory, t9.paraphrases[1].upper())
    assert (task.id, task.wording, task.text) == ("T9", "paraphrase:2", t9.paraphrases[1])
    assert task.targets == t9.targets and task.start_poses == t9.start_poses
    assert task_from_text(factory, t9.text).wording == "bundled"
    resolved = resolve_task(None, [t9.paraphrases[0]], None, 3)
    assert resolved.scenario.name == "factory" and resolved.task.id == "T9" and resolved.start_pose_index == 3


def test_free_text_is_free_and_names_objects_by_their_names() -> None:
    factory = load_scenario("factory")
    task = task_from_text(factory, "drive to the workbench please")
    assert (task.wording, task.kind, [t.object for t in task.targets]) == ("free", "target", ["T"])
    wander = task_from_text(factory, "what a lovely day")
    assert (wander.wording, wander.kind) == ("free", "explore")


def test_wordings_and_bad_wordings() -> None:
    t1 = load_scenario("factory").task("T1")
    assert task_wordings(t1) == ["bundled", "paraphrase:1", "paraphrase:2", "paraphrase:3"]
    assert in_wording(t1, "paraphrase:3").text == t1.paraphrases[2]
    with pytest.raises(BadInputError, match=r"task 'T1' has no wording 'paraphrase:9' \(wordings: bundled, "):
        in_wording(t1, "paraphrase:9")


def test_the_wording_factor_runs_each_task_in_each_wording(tmp_path: Path) -> None:
    grid = GridSpec(scenario="factory", tasks=["T1", "T6"], poses=[2], wording=["bundled", "paraphrase:2"])
    episodes = expand(grid)
    assert [(e.task_id, e.factors["wording"]) for e in episodes] == [
        ("T1", "bundled"), ("T1", "paraphrase:2"), ("T6", "bundled"), ("T6", "paraphrase:2"),
    ]  # fmt: skip
    specs = [e.spec(tmp_path, "factory") for e in episodes]
    factory = load_scenario("factory")
    assert specs[0].task_id == "T1" and specs[0].task_text is None
    assert specs[1].task_id is None and specs[1].task_text == factory.task("T1").paraphrases[1]
    assert len({e.dir_name for e in episodes}) == 4 and episodes[0].seed == episodes[1].seed
    with pytest.raises(BadInputError, match="has no wording 'paraphrase:7'"):
        expand(GridSpec(scenario="factory", tasks=["T1"], wording=["paraphrase:7"]))
