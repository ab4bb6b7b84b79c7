"""The hybrid planner's decision by scored option texts (SayCan-style), for models too small to choose by number.

A 135M model cannot write the number of the right option (its answer digit follows its digit prior, not
the menu), but it can tell how likely a text is as the continuation of the task. Each decision therefore
asks the backend for log-probabilities, never for an answer (Ahn et al. 2022, SayCan; docs/sources.md):

- **Relevance of a landmark** is the domain-conditional pointwise mutual information of its name
  with the task (`llmnav.relevance`; Holtzman et al. 2021): log P(" <name>" | TARGET_PROMPT with the
  task) minus log P(" <name>" | the same prompt with the content-free task "N/A"). Subtracting the
  content-free term removes the model's prior for short, frequent names. Both terms depend only on the
  task and the name, so each name is scored once per episode, when it first appears on the menu.
- **Intent** (once per episode): whether the task is done by turning on the spot or by going somewhere,
  the PMI of the two phrases in `INTENTS` after INTENT_PROMPT. A task that names no place ("look
  around", "spin") is served by one full turn, then Finish.

The decision rule, given the menu the planner built (`Candidate`s: landmarks with their distances, the
landmarks the robot stands at, frontiers, the full turn when offered, Finish):
1. Intent "turn": the full turn until one has been made, then Finish.
2. Intent "go", before any full turn and without a published map: the full turn (look before choosing).
3. Every known landmark gets the value PMI - `distance_cost` x distance [m] (the affordance term: between
   equally relevant landmarks, such as two oil barrels, the nearer wins). The best one is the target.
4. A target is sure when its PMI reaches `sure_pmi`. An unsure one is not taken while there is more to
   see: explore the frontier worth the most first (its length discounted by the drive to it), at most
   max(`explore_budget`, the world's area / `explore_area_m2`) times in an episode. Exploring
   ends early when something new comes into view, and the decision is made again (such an exploration is
   not counted against the budget).
5. With nothing left to explore, a target whose PMI reaches `min_pmi` (the task makes it e times
   likelier) is taken; below that, look around where the robot has not yet, else the episode ends
   `not_found`: a place the scores reject is never driven to or finished at, and neither is anything
   when nothing was seen at all.
6. At the target: an unsure one gets one more look around from there (a better match may come into
   view), then Finish. Otherwise go to the target.

`sure_pmi` and `min_pmi` were set on task wordings that are not part of this repository (targets scored
6-12 nats, unrelated landmarks up to 5), never on the bundled tasks.

The policy backends score too (`llmnav.backends.policy`), so the same rule runs on null scores: what a
policy reaches in this mode is the rule's merit, and the tables show it beside the model.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal

from llmnav.relevance import CONTENT_FREE_TASK, TARGET_PROMPT, TextRelevance

if TYPE_CHECKING:
    from llmnav.planners.base import EpisodeContext

INTENT_PROMPT = "A mobile robot carries out the user's task.\nTask: {task}\nTo do this, the robot will"
__all__ = ["CONTENT_FREE_TASK", "INTENT_PROMPT", "TARGET_PROMPT", "Candidate", "Decision", "ScoredChooser"]
INTENTS: tuple[tuple[str, str], ...] = (("go", " drive to something"), ("turn", " turn around on the spot"))

CandidateKind = Literal["landmark", "frontier", "scan", "complete"]
Intent = Literal["go", "turn"]


@dataclass(frozen=True)
class ScoringConfig:
    """Numbers of the scored decision."""

    min_pmi: float = 1.0  # [nats] a landmark the task makes less than e times likelier is no target
    sure_pmi: float = 5.0  # [nats] a landmark this relevant is taken without exploring further
    explore_budget: int = 8  # [decisions] explorations before an unsure target is taken, at the least ...
    explore_area_m2: float = 25.0  # [m^2] ... or one per this much of the world's extent (a room's worth)
    distance_cost: float = 0.05  # [nats/m] affordance: among equally relevant landmarks, the nearer wins


@dataclass(frozen=True)
class Candidate:
    """One menu entry as the scored decision sees it."""

    number: int
    kind: CandidateKind
    names: tuple[str, ...] = ()  # landmark: its name; complete: the names of the landmarks the robot is at
    distance_m: float = 0.0  # [m] from the robot to where the option drives
    utility: float = 0.0  # frontier: what exploring it is worth (`llmnav.planners.hybrid.menu.frontier_utility`)


@dataclass
class Decision:
    """The chosen option and why (logged with every decision, shown by the viewer)."""

    number: int
    rule: str  # which step of the rule decided, in a few words
    intent: Intent
    scores: dict[str, float] = field(default_factory=dict)  # landmark name -> PMI [nats]
    not_found: bool = False  # nothing fits the task and nothing is left to look at: the episode ends so

    def to_log(self) -> dict[str, Any]:
        """Event fields."""
        out: dict[str, Any] = {
            "option": self.number,
            "rule": self.rule,
            "intent": self.intent,
            "pmi": {name: round(value, 3) for name, value in self.scores.items()},
        }
        return out | ({"not_found": True} if self.not_found else {})


class ScoredChooser:
    """Chooses menu entries by scores (see the module docstring)."""

    def __init__(
        self,
        ctx: EpisodeContext,
        task: str,
        *,
        mapped: bool,
        config: ScoringConfig | None = None,
        area_m2: float = 0.0,
    ) -> None:
        """`area_m2` [m^2]: the world's extent (what the explorer may know): a bigger building gets more looks."""
        self.cfg = config or ScoringConfig()
        self.area_m2 = area_m2
        self.step: int | None = None  # the decision the scores are logged with
        self.scorer = TextRelevance(lambda request: ctx.score(request, self.step), task)
        self.mapped = mapped  # a published map lists every landmark: no need to look before choosing
        self.intent: Intent | None = None
        self.explored = 0  # decisions that chose to explore

    def explore_budget(self) -> int:
        """[decisions] explorations allowed before an unsure target is taken."""
        return max(self.cfg.explore_budget, math.ceil(self.area_m2 / self.cfg.explore_area_m2))

    def relevance(self, names: list[str], step: int | None) -> dict[str, float]:
        """PMI [nats] of landmark names with the task."""
        self.step = step
        return self.scorer.pmi(TARGET_PROMPT, names)

    def _intent(self, step: int | None) -> Intent:
        if self.intent is None:
            self.step = step
            scores = self.scorer.pmi(INTENT_PROMPT, [text.strip() for _, text in INTENTS])
            best = max(INTENTS, key=lambda item: scores[item[1].strip()])  # ties: the first (go)
            self.intent = "turn" if best[0] == "turn" else "go"
        return self.intent

    def choose(
        self, candidates: list[Candidate], *, turned: bool, step: int | None, explored: int | None = None
    ) -> Decision:
        """The option to take now; `turned`: a full turn has been made in this episode.

        `explored`: explorations carried to their end so far, which the budget counts (default: every
        choice to explore). One cut short because something new came into view is not spent: it hands
        the decision back with more to go on, and what can come into view is finite.
        """
        by_kind: dict[str, list[Candidate]] = {}
        for candidate in candidates:
            by_kind.setdefault(candidate.kind, []).append(candidate)
        finish = by_kind["complete"][0]
        scan = by_kind.get("scan", [None])[0]
        intent = self._intent(step)
        if intent == "turn":
            if not turned and scan is not None:
                return Decision(scan.number, "the task asks for a turn", intent)
            return Decision(finish.number, "turned: done", intent)
        if not turned and scan is not None and not self.mapped:
            return Decision(scan.number, "look around before choosing", intent)
        places = [c for c in by_kind.get("landmark", []) if c.names]
        here = list(finish.names)
        names = [*here, *(c.names[0] for c in places)]
        scores = self.relevance(names, step) if names else {}
        # (value, candidate or None for "where the robot stands")
        options: list[tuple[float, str, Candidate | None]] = [(scores[n], n, None) for n in here]
        options += [(scores[c.names[0]] - self.cfg.distance_cost * c.distance_m, c.names[0], c) for c in places]
        if not options:
            if by_kind.get("frontier"):
                self.explored += 1
                return self._frontier(by_kind, intent, scores, "nothing known yet")
            if scan is not None:
                return Decision(scan.number, "nothing known yet: look around", intent, scores)
            why = "not found: no reachable place is known and nothing is left to explore"
            return Decision(finish.number, why, intent, scores, True)
        value, name, best = max(options, key=lambda item: item[0])
        sure = scores[name] >= self.cfg.sure_pmi
        spent = self.explored if explored is None else explored
        if not sure and spent < self.explore_budget() and by_kind.get("frontier"):
            self.explored += 1
            return self._frontier(by_kind, intent, scores, f"{name} {scores[name]:+.1f} is unsure")
        if scores[name] < self.cfg.min_pmi:
            if scan is not None:
                why = f"no known place fits ({name} {scores[name]:+.1f}): look around"
                return Decision(scan.number, why, intent, scores)
            # Never Finish at, or drive to, a place the scores reject: say so instead, and why the search ended.
            ended = f"the exploration budget is spent ({spent})" if by_kind.get("frontier") else "nothing is left"
            why = f"not found: no known place fits ({name} {scores[name]:+.1f}) and {ended} to explore"
            return Decision(finish.number, why, intent, scores, True)
        if best is None:
            if not sure and scan is not None and not self.mapped:
                return Decision(scan.number, f"at {name}: look around once more", intent, scores)
            return Decision(finish.number, f"at {name}", intent, scores)
        return Decision(best.number, f"go to {name}", intent, scores)

    @staticmethod
    def _frontier(by_kind: dict[str, list[Candidate]], intent: Intent, scores: dict[str, float], why: str) -> Decision:
        """Explore the frontier worth the most (ties: the nearer)."""
        best = max(by_kind["frontier"], key=lambda c: (c.utility, -c.distance_m))
        return Decision(best.number, f"{why}: explore", intent, scores)
