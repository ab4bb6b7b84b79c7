"""The hybrid planner's decision by scored option texts (SayCan-style), for models too small to choose by number.

A 135M model cannot write the number of the right option (its answer digit follows its digit prior, not
the menu), but it can tell how likely a text is as the continuation of the task. Each decision therefore
asks the backend for log-probabilities, never for an answer (Ahn et al. 2022, SayCan; docs/sources.md):

- **Relevance of a landmark** is the domain-conditional pointwise mutual information of its name
  with the task (`llmnav.sensing.relevance`; Holtzman et al. 2021): log P(" <name>" | TARGET_PROMPT with the
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
   see: explore a frontier first, at most max(`explore_budget`, the world's area / `explore_area_m2`)
   times in an episode. Which frontier (`-o explore`): the nearest; the most useful (its length
   discounted by the drive to it); or, `scored`, the one of highest `frontier_value`: the utility times
   the likelihood ratio of its description ("the bedroom": the room the landmarks seen within
   `describe_radius_m` of it suggest, else those landmarks) with the task, the PMI after
   FRONTIER_PROMPT against the content-free task (docs/frontier-values.md). Exploring ends early when
   something new comes into view, and the decision is made again (such an exploration is not
   counted against the budget).
5. Once the budget is spent (or nothing is left to explore), a target whose PMI reaches `min_pmi` (the
   task makes it e times likelier) is taken. Below that there is nothing to take: explore on while
   frontiers remain (the budget only bounds the search before an unsure target is taken), then look
   around where the robot has not yet, else the episode ends `not_found`: a place the scores reject is
   never driven to or finished at, and neither is anything when nothing was seen at all.
6. At the target: an unsure one gets one more look around from there (a better match may come into
   view), then Finish. Otherwise go to the target.

Relational places ("spot between the stairs and the oil barrel", "spot beside the stairs"; built from the
landmarks seen, `menu.relational_options`, for a task that words a relation) join the landmarks in step
3, scored like names after TARGET_PROMPT (with their spot in the request, for oracle answers); one counts
only where its PMI exceeds that of each landmark it names, so a relation is taken when the task asks for
it, not as a nearer stand-in for its landmark.

`sure_pmi` and `min_pmi` were set on task wordings that are not part of this repository (targets scored
6-12 nats, unrelated landmarks up to 5), never on the bundled tasks.

The policy backends score too (`llmnav.backends.policy`), so the same rule runs on null scores: what a
policy reaches in this mode is the rule's merit, and the tables show it beside the model.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal

from llmnav.core.chat import ScoreRequest
from llmnav.sensing.relevance import CONTENT_FREE_TASK, TARGET_PROMPT, TextRelevance

if TYPE_CHECKING:
    from llmnav.planners.base import EpisodeContext

INTENT_PROMPT = "A mobile robot carries out the user's task.\nTask: {task}\nTo do this, the robot will"
# A frontier's description after the task, against the content-free task (`frontier_value`).
FRONTIER_PROMPT = "A mobile robot carries out the user's task.\nTask: {task}\nTo do this, the robot explores toward"
# The room a landmark suggests: each room word's PMI after this prompt (against "N/A"); a set of landmarks
# suggests the room word of the highest summed PMI (`ScoredChooser.room`).
ROOM_PROMPT = "In a building, the room with {task} is the"
# Common rooms of homes, offices and industrial buildings: a fixed, general list, not read from any scenario.
ROOM_WORDS = (
    "kitchen",
    "bedroom",
    "bathroom",
    "living room",
    "dining room",
    "office",
    "meeting room",
    "hallway",
    "storage room",
    "workshop",
    "garage",
    "laundry room",
)
UNDESCRIBED = "unexplored space"  # a frontier with no known landmark near it
__all__ = [
    "CONTENT_FREE_TASK",
    "FRONTIER_PROMPT",
    "INTENT_PROMPT",
    "TARGET_PROMPT",
    "Candidate",
    "Decision",
    "ScoredChooser",
    "frontier_value",
]
INTENTS: tuple[tuple[str, str], ...] = (("go", " drive to something"), ("turn", " turn around on the spot"))

CandidateKind = Literal["landmark", "frontier", "scan", "complete"]
Intent = Literal["go", "turn"]
Explore = Literal["nearest", "utility", "scored"]


def frontier_value(utility: float, pmi: float) -> float:
    """A scored frontier's value: log(utility) + PMI, i.e. the utility times the likelihood ratio e^PMI.

    `utility` (`menu.frontier_utility`: length [m] x exp(-decay x distance)) is what exploring the frontier
    is worth with no idea where the target is; the PMI [nats] of its description says how many times
    likelier the task makes heading toward what lies near it. Multiplying the two weighs them without a
    tuned weight: one nat of relevance is worth a factor e of utility (a frontier 5 m farther at the
    default decay of 0.2/m). A description the task neither favours nor disfavours (PMI 0) leaves the
    utility as it was, so with no evidence the explorer is the utility explorer.
    """
    return math.log(max(utility, 1e-9)) + pmi


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
    # landmark: its name (a relational place: its words, then the landmarks it names); complete: the names of
    # the landmarks the robot is at; frontier: the landmarks near it
    names: tuple[str, ...] = ()
    distance_m: float = 0.0  # [m] from the robot to where the option drives
    utility: float = 0.0  # frontier: what exploring it is worth (`llmnav.planners.hybrid.menu.frontier_utility`)
    # [m] frontier: where it drives; relational place: where it lies (oracle answers judge both by where)
    place: tuple[float, float] | None = None
    standing: bool = False  # relational place: the robot is there


@dataclass
class Decision:
    """The chosen option and why (logged with every decision, shown by the viewer)."""

    number: int
    rule: str  # which step of the rule decided, in a few words
    intent: Intent
    scores: dict[str, float] = field(default_factory=dict)  # landmark name -> PMI [nats]
    not_found: bool = False  # nothing fits the task and nothing is left to look at: the episode ends so
    # every frontier on the menu: option, description, utility, PMI and value (`frontier_value`)
    frontiers: list[dict[str, Any]] = field(default_factory=list)

    def to_log(self) -> dict[str, Any]:
        """Event fields."""
        out: dict[str, Any] = {
            "option": self.number,
            "rule": self.rule,
            "intent": self.intent,
            "pmi": {name: round(value, 3) for name, value in self.scores.items()},
        }
        if self.frontiers:
            out["frontiers"] = self.frontiers
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
        explore: Explore = "utility",
    ) -> None:
        """`area_m2` [m^2]: the world's extent (what the explorer may know): a bigger building gets more looks.

        `explore`: which frontier to explore: the nearest, the most useful (`Candidate.utility`), or the
        most valuable by its description's scores (`frontier_value`).
        """
        self.cfg = config or ScoringConfig()
        self.area_m2 = area_m2
        self.explore = explore
        self.step: int | None = None  # the decision the scores are logged with
        self._score = lambda request: ctx.score(request, self.step)
        self.task = task
        self.scorer = TextRelevance(self._score, task)
        self._rooms: dict[str, dict[str, float]] = {}  # landmark name -> PMI [nats] of each room word
        self._places: dict[tuple[str, tuple[float, float]], float] = {}  # relational place -> PMI [nats]
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
        the decision back with more to go on, and what can come into view is finite. The decision lists
        every frontier on the menu with what is known near it and its utility (and, where it chose by
        scores, each one's description, PMI and value).
        """
        decision = self._choose(candidates, turned=turned, step=step, explored=explored)
        if not decision.frontiers:
            decision.frontiers = [_row(c) for c in candidates if c.kind == "frontier"]
        return decision

    def _choose(
        self, candidates: list[Candidate], *, turned: bool, step: int | None, explored: int | None
    ) -> Decision:
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
        places = [c for c in by_kind.get("landmark", []) if c.names and c.place is None]
        relational = [c for c in by_kind.get("landmark", []) if c.names and c.place is not None]
        here = list(finish.names)
        names = [*here, *(c.names[0] for c in places)]
        scores = self.relevance(names, step) if names else {}
        between = self.place_relevance(relational)
        # (value, PMI, name, candidate or None for "where the robot stands")
        options: list[tuple[float, float, str, Candidate | None]] = [(scores[n], scores[n], n, None) for n in here]
        options += [
            (scores[c.names[0]] - self.cfg.distance_cost * c.distance_m, scores[c.names[0]], c.names[0], c)
            for c in places
        ]
        for c, pmi in zip(relational, between, strict=True):
            scores[_place_label(c)] = pmi
            # A relation counts only where the task asks for it: more relevant than each landmark it names
            # (else "spot between the boxes and the fire" would take the boxes' score to a spot metres off).
            parts = self.relevance(list(c.names[1:]), step) if c.names[1:] else {}
            if parts and pmi <= max(parts.values()):
                continue
            # a relational place the robot stands at is "where the robot stands", like Finish's landmarks
            options.append((pmi - self.cfg.distance_cost * c.distance_m, pmi, c.names[0], None if c.standing else c))
        if not options:
            if by_kind.get("frontier"):
                self.explored += 1
                return self._frontier(by_kind, intent, scores, "nothing known yet")
            if scan is not None:
                return Decision(scan.number, "nothing known yet: look around", intent, scores)
            why = "not found: no reachable place is known and nothing is left to explore"
            return Decision(finish.number, why, intent, scores, True)
        value, pmi, name, best = max(options, key=lambda item: item[0])
        sure = pmi >= self.cfg.sure_pmi
        spent = self.explored if explored is None else explored
        if not sure and spent < self.explore_budget() and by_kind.get("frontier"):
            self.explored += 1
            return self._frontier(by_kind, intent, scores, f"{name} {pmi:+.1f} is unsure")
        if pmi < self.cfg.min_pmi:
            # The budget bounds exploring before an unsure target is taken; with no known place worth
            # taking there is nothing to take yet, so the search goes on while anything is left to explore.
            if by_kind.get("frontier"):
                self.explored += 1
                return self._frontier(by_kind, intent, scores, f"no known place fits ({name} {pmi:+.1f})")
            if scan is not None:
                why = f"no known place fits ({name} {pmi:+.1f}): look around"
                return Decision(scan.number, why, intent, scores)
            # Never Finish at, or drive to, a place the scores reject: say so instead.
            why = f"not found: no known place fits ({name} {pmi:+.1f}) and nothing is left to explore"
            return Decision(finish.number, why, intent, scores, True)
        if best is None:
            if not sure and scan is not None and not self.mapped:
                return Decision(scan.number, f"at {name}: look around once more", intent, scores)
            return Decision(finish.number, f"at {name}", intent, scores)
        return Decision(best.number, f"go to {name}", intent, scores)

    def _frontier(
        self, by_kind: dict[str, list[Candidate]], intent: Intent, scores: dict[str, float], why: str
    ) -> Decision:
        """Explore the frontier `explore` ranks first (ties: the nearer)."""
        frontiers = by_kind["frontier"]
        rows: list[dict[str, Any]] = []
        if self.explore == "nearest":
            best = min(frontiers, key=lambda c: c.distance_m)
        elif self.explore == "utility":
            best = max(frontiers, key=lambda c: (c.utility, -c.distance_m))
        else:
            texts = [self.describe(c.names) for c in frontiers]
            pmi = self.frontier_pmi(texts, [c.place or (0.0, 0.0) for c in frontiers])
            values = [frontier_value(c.utility, p) for c, p in zip(frontiers, pmi, strict=True)]
            best = max(zip(values, frontiers, strict=True), key=lambda item: (item[0], -item[1].distance_m))[1]
            rows = [
                _row(c) | {"description": text, "pmi": round(p, 3), "value": round(v, 3)}
                for c, text, p, v in zip(frontiers, texts, pmi, values, strict=True)
            ]
        decision = Decision(best.number, f"{why}: explore", intent, scores)
        decision.frontiers = rows
        return decision

    def place_relevance(self, relational: list[Candidate]) -> list[float]:
        """PMI [nats] of relational places ("spot between the stairs and the oil barrel") with the task.

        Scored like names (after TARGET_PROMPT, against the content-free task), with where each lies in
        the request (`ScoreRequest.places`): oracle answers judge the spot, not the words, since the same
        words name a spot beside each of several oil barrels. Each (words, spot to `PLACE_CACHE_M`) once.
        """
        keys = [(c.names[0], _rounded(c.place)) for c in relational]
        new = [key for key in dict.fromkeys(keys) if key not in self._places]
        if new:
            continuations = tuple(" " + text for text, _ in new)
            where = tuple(spot for _, spot in new)
            with_task = self._score(ScoreRequest(TARGET_PROMPT.format(task=self.task), continuations, where))
            free = self._score(ScoreRequest(TARGET_PROMPT.format(task=CONTENT_FREE_TASK), continuations, where))
            for key, a, b in zip(new, with_task.scores, free.scores, strict=True):
                self._places[key] = a.logprob - b.logprob
        return [self._places[key] for key in keys]

    # --- frontier descriptions ----------------------------------------------------------------------
    def describe(self, names: tuple[str, ...]) -> str:
        """A frontier's description: the room its nearby landmarks suggest, else the landmarks themselves.

        "the living room" when the sofa and the armchair make it at least `min_pmi` likelier; without such
        a room, "the sofa and the armchair"; with no landmark near, UNDESCRIBED. The room alone, not the
        room with its landmarks: the room carries what the landmarks say about where the target is, and a
        short text that recurs decision after decision is scored once (`llmnav.backends.memo`), where "the
        living room with the sofa and the armchair" cost 10 tokens with each new set of landmarks.
        """
        if not names:
            return UNDESCRIBED
        room = self.room(names)
        return f"the {room}" if room else _listed(names)

    def room(self, names: tuple[str, ...]) -> str:
        """The room the landmarks `names` suggest together, if it is at least `min_pmi` [nats] likelier.

        Each landmark is asked about once (ROOM_PROMPT, "In a building, the room with the bed is the", and
        every room word, against "N/A"), and a set's PMI for a room word is the sum over its landmarks:
        the log-likelihood ratio when landmarks are independent given the room (naive Bayes). A new set of
        known landmarks asks nothing new, where one question per set cost 12 continuations each.
        """
        totals = dict.fromkeys(ROOM_WORDS, 0.0)
        for name in dict.fromkeys(names):
            for word, pmi in self._room_pmi(name).items():
                totals[word] += pmi
        best = max(ROOM_WORDS, key=lambda word: totals[word])  # ties: the first
        return best if totals[best] >= self.cfg.min_pmi else ""

    def _room_pmi(self, name: str) -> dict[str, float]:
        """PMI [nats] of each room word for one landmark (asked once per episode; the backend may remember)."""
        if name not in self._rooms:
            self._rooms[name] = TextRelevance(self._score, _listed((name,))).pmi(ROOM_PROMPT, list(ROOM_WORDS))
        return self._rooms[name]

    def frontier_pmi(self, texts: list[str], places: list[tuple[float, float]]) -> list[float]:
        """PMI [nats] of each frontier description with the task, against the content-free task.

        One request pair for the menu's frontiers, never cached: oracle answers judge each by where it
        lies (`ScoreRequest.places`), and the same words may describe two frontiers.
        """
        continuations = tuple(" " + text for text in texts)
        where = tuple((round(x, 3), round(y, 3)) for x, y in places)
        with_task = self._score(ScoreRequest(FRONTIER_PROMPT.format(task=self.task), continuations, where))
        free = self._score(ScoreRequest(FRONTIER_PROMPT.format(task=CONTENT_FREE_TASK), continuations, where))
        return [a.logprob - b.logprob for a, b in zip(with_task.scores, free.scores, strict=True)]


def _row(frontier: Candidate) -> dict[str, Any]:
    """A frontier as the decision logs it: option, where [m], what is near it, its utility."""
    row: dict[str, Any] = {"option": frontier.number}
    if frontier.place is not None:
        row["at"] = [round(frontier.place[0], 2), round(frontier.place[1], 2)]
    return row | {"near": list(frontier.names), "utility": round(frontier.utility, 3)}


PLACE_CACHE_M = 0.5  # [m] a relational place's spot moves this little as its landmarks are seen again


def _rounded(place: tuple[float, float] | None) -> tuple[float, float]:
    """A spot on the `PLACE_CACHE_M` lattice (what a relational place's score is kept under)."""
    x, y = place or (0.0, 0.0)
    return (round(round(x / PLACE_CACHE_M) * PLACE_CACHE_M, 3), round(round(y / PLACE_CACHE_M) * PLACE_CACHE_M, 3))


def _place_label(candidate: Candidate) -> str:
    """A relational place as the decision's scores name it: its words and where it lies."""
    x, y = candidate.place or (0.0, 0.0)
    return f"{candidate.names[0]} ({x:.1f}, {y:.1f})"


def _listed(names: tuple[str, ...]) -> str:
    """'the sofa', 'the sofa and the armchair', 'the sofa, the rug and the armchair'."""
    items = [f"the {name}" for name in names]
    return items[0] if len(items) == 1 else f"{', '.join(items[:-1])} and {items[-1]}"
