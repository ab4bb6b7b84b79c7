"""The hybrid planner's oracle answers: what a perfect model would score or choose, from ground truth.

The hybrid asks two kinds of question, and a perfect model answers both from the task's true targets:

- **Scores** (the default decision, `llmnav.planners.hybrid.scoring`): a landmark's name after the task
  prompt scores `MATCH` when it names an acceptable target of the task (its label, an alias or its id),
  `MISMATCH` otherwise; every name after the content-free task scores `NEUTRAL`. The PMI is then
  +10 nats for a target and -10 for anything else, beyond the rule's "sure" threshold either way. The
  intent is "turn" for the rotate and explore tasks, "go" for the others.
- **Frontier descriptions** (`-o explore=scored`): the frontier that leads toward the target scores
  `MATCH` after the task, every other `NEUTRAL`: PMI +10 for it and 0 for the rest, whatever their words
  say. "Leads toward" is judged by where the frontier lies (`ScoreRequest.places`), not by its words: the
  one with the shortest collision-free path on the true map to within the success radius of an
  acceptable target (the `oracle` planner's geometry, `llmnav.mapping.targets.goal_distance`), which is
  the way into the target's room. The room a set of landmarks suggests is not the oracle's business:
  every room word scores `NEUTRAL`.
- **Relational places** ("spot between the stairs and the oil barrel", `menu.relational_options`): scored
  like names, but judged by where the spot lies (`ScoreRequest.places`): `MATCH` within `PLACE_MATCH_M`
  of an acceptable target point, `MISMATCH` elsewhere. This is how factory T4's point target ("Go
  between the stairs and the oil barrels") gets a name the hybrid can choose.
- **An option number** (`--decide generate`): Finish where the robot stands at an acceptable target;
  else the option that drives to one; for a rotate or explore task the full turn, then Finish; else the
  full turn when offered (look before choosing); else the frontier whose direction is closest to the
  true bearing of the nearest target; else Finish.

What the hybrid can find is still what its own sensors reveal: a target it never detects cannot be
chosen, and a point target is reachable only as a relational place between or beside landmarks it has
seen (scored decisions). That is the planner's ceiling.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from llmnav.mapping.targets import goal_distance
from llmnav.planners.hybrid.menu import SECTORS
from llmnav.planners.hybrid.scoring import FRONTIER_PROMPT, INTENT_PROMPT, INTENTS, ROOM_PROMPT
from llmnav.sensing.relevance import CONTENT_FREE_TASK, TARGET_PROMPT

if TYPE_CHECKING:
    from llmnav.core.chat import ChatRequest, ScoreRequest
    from llmnav.planners.base import GroundTruth

MATCH, MISMATCH, NEUTRAL = 0.0, -20.0, -10.0  # [nats] see the module docstring
PLACE_MATCH_M = 1.0  # [m] a relational place this close to a target point is that target, whatever its words
TOWARD_RADIUS_M = 2.5  # [m] a frontier leads toward the target that its path reaches within this (full credit)
_MENU_LINE = re.compile(r"^\s*(\d+)\.\s+(.+?)\s*$", re.MULTILINE)
_GO_TO = re.compile(r"^Go to (.+?)(?:,|$)")
_FINISH_AT = re.compile(r"^Finish \(at (.+)\)$")
_EXPLORE = re.compile(r"^Explore, .*?([a-z-]+)$")


@dataclass
class HybridAnswerKey:
    """The `AnswerKey` of one hybrid episode (see the module docstring)."""

    truth: GroundTruth
    _turned: bool = False  # the full turn has been chosen (generated decisions)

    @property
    def can_score(self) -> bool:
        """The hybrid decides by scores where the backend can."""
        return True

    def _names(self) -> set[str]:
        """Every name of every acceptable target object, lower-cased."""
        scenario = self.truth.scenario
        return {n for t in self.truth.task.targets if t.object for n in scenario.object(t.object).names()}

    def _is_target(self, name: str) -> bool:
        return name.strip().lower() in self._names()

    def scores(self, request: ScoreRequest) -> tuple[float, ...]:
        """Target names high, others low; the intent the task's kind asks for (see the module docstring)."""
        n = len(request.continuations)
        task = self.truth.task.text
        if request.prefix in (
            TARGET_PROMPT.format(task=CONTENT_FREE_TASK),
            INTENT_PROMPT.format(task=CONTENT_FREE_TASK),
            FRONTIER_PROMPT.format(task=CONTENT_FREE_TASK),
        ):
            return (NEUTRAL,) * n
        if request.prefix == FRONTIER_PROMPT.format(task=task):
            return self._frontier_scores(request)
        if request.prefix == TARGET_PROMPT.format(task=task) and request.places:
            return self._place_scores(request)
        if request.prefix.startswith(ROOM_PROMPT.split("{task}", 1)[0]):
            return (NEUTRAL,) * n
        if request.prefix == INTENT_PROMPT.format(task=task):
            wanted = dict(INTENTS)["go" if self.truth.task.kind == "target" else "turn"]
            return tuple(MATCH if c.strip() == wanted.strip() else MISMATCH for c in request.continuations)
        return tuple(MATCH if self._is_target(c) else MISMATCH for c in request.continuations)

    def _place_scores(self, request: ScoreRequest) -> tuple[float, ...]:
        """Relational places: MATCH for a spot within PLACE_MATCH_M of an acceptable target point, else MISMATCH."""
        points = self.truth.scenario.target_points(self.truth.task)
        return tuple(
            MATCH if any(math.dist(place, point) <= PLACE_MATCH_M for point in points) else MISMATCH
            for place in request.places
        )

    def _frontier_scores(self, request: ScoreRequest) -> tuple[float, ...]:
        """MATCH for the frontier nearest an acceptable target by path on the true map, NEUTRAL for the others."""
        n = len(request.continuations)
        points = self.truth.scenario.target_points(self.truth.task)
        if len(request.places) != n or not points:
            return (NEUTRAL,) * n
        lengths = [goal_distance(self.truth.scenario, points, place, TOWARD_RADIUS_M) for place in request.places]
        reachable = [(length, index) for index, length in enumerate(lengths) if length is not None]
        if not reachable:
            return (NEUTRAL,) * n
        best = min(reachable)[1]
        return tuple(MATCH if index == best else NEUTRAL for index in range(n))

    def answer(self, request: ChatRequest) -> str:
        """The option number a perfect model would choose from the menu of the latest user turn."""
        user = next(m.text for m in reversed(request.messages) if m.role == "user")
        menu = {int(number): text for number, text in _MENU_LINE.findall(user)}
        choice = self._choose(menu)
        body: dict[str, Any] = {"option": choice}
        schema = request.json_schema or {}
        for name in schema.get("required", []):
            if name != "option":
                body[name] = "oracle answer from ground truth"
        return json.dumps(body)

    def _choose(self, menu: dict[int, str]) -> int:
        finish = next((n for n, t in menu.items() if t.startswith("Finish")), max(menu, default=1))
        turn = next((n for n, t in menu.items() if t.startswith("Turn")), None)
        if self.truth.task.kind != "target":
            if turn is not None and not self._turned:
                self._turned = True
                return turn
            return finish
        at = _FINISH_AT.match(menu.get(finish, ""))
        if at and any(self._is_target(name) for name in at.group(1).split(", ")):
            return finish
        for number, text in menu.items():
            go = _GO_TO.match(text)
            if go and self._is_target(go.group(1)):
                return number
        if turn is not None and not self._turned:
            self._turned = True
            return turn
        explore = {n: m.group(1) for n, t in menu.items() if (m := _EXPLORE.match(t)) and m.group(1) in SECTORS}
        if explore:
            return min(explore, key=lambda n: _angle_between(SECTORS.index(explore[n]) * 45.0, self._bearing_deg()))
        return finish

    def _bearing_deg(self) -> float:
        """[deg] the true bearing of the nearest acceptable target from the robot's true pose."""
        pose = self.truth.pose()
        points = self.truth.scenario.target_points(self.truth.task)
        nearest = min(points, key=lambda p: pose.distance_to(*p))
        return math.degrees(pose.bearing_to(*nearest))


def _angle_between(a_deg: float, b_deg: float) -> float:
    """[deg] the unsigned difference of two directions."""
    return abs((a_deg - b_deg + 180.0) % 360.0 - 180.0)
