"""How relevant a text is to a task, by a language model's scores: domain-conditional PMI.

PMI(text) = log P(" text" | prompt with the task) - log P(" text" | the same prompt with the content-free
task "N/A") (Holtzman et al. 2021). Subtracting the content-free term removes the model's prior for
short, frequent texts, so what remains is how much the task itself makes the text likelier. Planners use
it to ground a task in landmark names (hybrid, waypoints) without asking a small model to write an answer.
Each text is scored once per task: both terms depend only on the task and the text.
"""

from __future__ import annotations

from collections.abc import Callable

from llmnav.core.chat import ScoreRequest, ScoreResult

# The prompts are plain text (no chat template): the model continues them. No example, no alias and no
# answer: the task's own words are all the model gets.
TARGET_PROMPT = "A mobile robot carries out the user's task.\nTask: {task}\nThe robot drives to the"
CONTENT_FREE_TASK = "N/A"

Scorer = Callable[[ScoreRequest], ScoreResult]


class TextRelevance:
    """PMI of texts with one task, each text scored once (the content-free term too)."""

    def __init__(self, score: Scorer, task: str) -> None:
        self._score = score
        self._task = task
        self._pmi: dict[tuple[str, str], float] = {}

    def pmi(self, template: str, texts: list[str]) -> dict[str, float]:
        """PMI [nats] of each text (a leading space is added) after `template` with the task vs "N/A"."""
        new = [t for t in dict.fromkeys(texts) if (template, t) not in self._pmi]
        if new:
            continuations = tuple(" " + t.strip() for t in new)
            with_task = self._score(ScoreRequest(template.format(task=self._task), continuations))
            free = self._score(ScoreRequest(template.format(task=CONTENT_FREE_TASK), continuations))
            for text, a, b in zip(new, with_task.scores, free.scores, strict=True):
                self._pmi[(template, text)] = a.logprob - b.logprob
        return {t: self._pmi[(template, t)] for t in texts}


def most_relevant(score: Scorer, task: str, names: list[str]) -> tuple[str, dict[str, float]]:
    """The name the task makes likeliest as where the robot drives to, and every name's PMI [nats]."""
    if not names:
        raise ValueError("no names to choose from")
    values = TextRelevance(score, task).pmi(TARGET_PROMPT, names)
    return max(names, key=lambda n: values[n]), values
