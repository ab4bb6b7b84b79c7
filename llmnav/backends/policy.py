"""Answers with no model: the null policies (the floor) and `policy:oracle` (the ceiling).

`policy:first`, `policy:random[:SEED]` and `policy:keyword` answer from the request alone;
`policy:oracle` gives the answers a perfect model would give.

A null policy answers any request by reading only its JSON Schema (and, for `keyword`, the texts the
request shows beside each allowed value). It tells how much of a planner's result the planner itself earns:
a model that does no better than "always answer 1" has added nothing. Its answers pass through the same
guard, run log and replay as any model's.

How an answer is built from the schema, node by node:
- an `enum` (menu numbers, commands, object ids): `first` takes the first listed value, `random` a seeded
  choice, `keyword` the value whose text shares the most words with the task (ties: the earlier value);
- a number or integer: inside the schema's `minimum`/`maximum` (and exclusive bounds) when given; with no
  bounds `DEFAULT_NUMBER` (`random`: uniform in [0, `DEFAULT_NUMBER`]). Range rules the schema does not state
  (the stepwise guard's "0 < metres ≤ 5", the FSM's velocity box) are the guard's to enforce, and a rejected
  answer is corrected like any model's: `random` draws again because the correction turn changes the request;
- an object: every property in schema order (required ones at least); an array: `minItems` (at least one)
  items; a string: a short fixed text (`minLength` honoured); a boolean: false.

`random` is seeded per request: the same seed and request always give the same answer, whatever ran before,
so episodes replay and ablations in any order agree.

Scoring requests (a prefix and continuations, see `ScoreRequest`) get the same policies as scores, so a
planner that decides by scores has the same null baselines: `first` scores by position (the first
continuation highest), `random` draws a seeded score per continuation, `keyword` counts the words each
continuation shares with the prefix's task line.

`policy:oracle` reads nothing itself: the runner attaches the episode planner's `AnswerKey` (built from
ground truth by the planner's `oracle_answers` hook) and the backend returns its answers and scores. A
planner that offers no answer key cannot run on it (bad input, before any run folder exists).
"""

from __future__ import annotations

import hashlib
import json
import math
import random
import re
from collections.abc import Callable, Sequence
from typing import Any

from llmnav.backends.base import (
    AnswerKey,
    Backend,
    BackendStatus,
    ChatRequest,
    ChatResult,
    ContinuationScore,
    Message,
    ScoreRequest,
    ScoreResult,
)
from llmnav.errors import BackendSpecError, ModelError

POLICIES = ("first", "random", "keyword", "oracle")
NULL_POLICIES = ("first", "random", "keyword")  # the floor; "oracle" is the ceiling
DEFAULT_NUMBER = 1.0  # value of a number the schema leaves unbounded (e.g. FRONT 1 m, a waypoint at 1)
FILLER_TEXT = "null policy"  # free-text fields (reasoning, goal): say what answered, nothing more
# Words too common to say anything about which option a task means.
STOPWORDS = frozenset(
    "a an and are at be by do for from i if in is it its me my of on or so some that the there this to "
    "up with you your can".split()
)
_WORD = re.compile(r"[a-z0-9]+")
_TASK_LINE = re.compile(r"^\s*(?:task|command)\s*:\s*(.+)$", re.IGNORECASE | re.MULTILINE)

Chooser = Callable[[Sequence[Any], "_Context"], Any]


def words(text: str) -> set[str]:
    """Content words of a text, lower-cased (`ROTATE_LEFT` -> rotate, left)."""
    return {w for w in _WORD.findall(text.lower().replace("_", " ")) if w not in STOPWORDS}


class _Context:
    """What a chooser may read: the request's messages (for option texts and the task) and its RNG."""

    def __init__(self, messages: Sequence[Message], rng: random.Random) -> None:
        self.messages = messages
        self.rng = rng

    def task(self) -> str:
        """The task: a `Task:`/`Command:` line of the latest user turn that has one, else the first user turn."""
        users = [m.text for m in self.messages if m.role == "user"]
        for text in reversed(users):
            match = _TASK_LINE.search(text)
            if match:
                return match.group(1).strip().strip('"')
        return users[0] if users else ""

    def option_text(self, value: Any) -> str:
        """The line that presents `value` (`3. Go to ...`, `- fire_ext: ...`), latest turn first; else the value."""
        pattern = re.compile(rf"^\s*(?:[-*]\s*)?{re.escape(str(value))}\s*[.):]\s*(.+)$", re.MULTILINE)
        for message in reversed(self.messages):
            if message.role == "assistant":
                continue
            match = pattern.search(message.text)
            if match:
                return f"{value} {match.group(1)}"
        return str(value)


def _first(values: Sequence[Any], ctx: _Context) -> Any:
    return values[0]


def _random(values: Sequence[Any], ctx: _Context) -> Any:
    return ctx.rng.choice(list(values))


def _keyword(values: Sequence[Any], ctx: _Context) -> Any:
    task = words(ctx.task())
    overlaps = [len(task & words(ctx.option_text(v))) for v in values]
    return values[overlaps.index(max(overlaps))]


_CHOOSERS: dict[str, Chooser] = {"first": _first, "random": _random, "keyword": _keyword}


def _number(node: dict[str, Any], policy: str, ctx: _Context, integer: bool) -> float | int:
    """A value inside the node's bounds (see the module docstring)."""
    step = 1 if integer else 0.01  # away from an exclusive bound
    low: float | None = node.get("minimum")
    if low is None and node.get("exclusiveMinimum") is not None:
        low = float(node["exclusiveMinimum"]) + step
    high: float | None = node.get("maximum")
    if high is None and node.get("exclusiveMaximum") is not None:
        high = float(node["exclusiveMaximum"]) - step
    if integer:  # the nearest whole numbers inside the bounds
        low = None if low is None else math.ceil(low)
        high = None if high is None else math.floor(high)
    if policy == "random":
        lo = low if low is not None else (high - DEFAULT_NUMBER if high is not None else 0.0)
        hi = high if high is not None else lo + DEFAULT_NUMBER
        if integer:
            value: float = ctx.rng.randint(int(lo), max(int(lo), int(hi)))
        else:
            value = min(max(round(ctx.rng.uniform(lo, hi), 3), lo), hi)
    else:
        value = DEFAULT_NUMBER
        if low is not None and value < low:
            value = low
        if high is not None and value > high:
            value = high
    return int(value) if integer else float(value)


def instance(schema: dict[str, Any], policy: str, ctx: _Context, defs: dict[str, Any] | None = None) -> Any:
    """A value valid for `schema`, chosen by `policy` (raises ValueError on a schema it cannot satisfy).

    `$ref`s point into the root's `$defs` (pydantic's plain `model_json_schema()` keeps them).
    """
    defs = schema.get("$defs", defs or {})
    if "$ref" in schema:
        return instance(defs[str(schema["$ref"]).rsplit("/", 1)[-1]], policy, ctx, defs)
    if "enum" in schema:
        values = list(schema["enum"])
        if not values:
            raise ValueError("an empty enum allows no value")
        return _CHOOSERS[policy](values, ctx)
    if "const" in schema:
        return schema["const"]
    for key in ("anyOf", "oneOf", "allOf"):
        if key in schema and schema[key]:
            return instance(schema[key][0], policy, ctx, defs)
    kind = schema.get("type")
    if isinstance(kind, list):
        kind = next((k for k in kind if k != "null"), "null")
    if kind == "object" or "properties" in schema:
        props: dict[str, Any] = schema.get("properties", {})
        required = schema.get("required", list(props))
        return {name: instance(sub, policy, ctx, defs) for name, sub in props.items() if name in required}
    if kind == "array":
        # A tuple (`prefixItems`, e.g. the FSM's [v, w]) gets one value per position; `items: false`
        # then forbids anything after them.
        fixed = [instance(sub, policy, ctx, defs) for sub in schema.get("prefixItems", [])]
        items = schema.get("items", {})
        count = max(0 if fixed else 1, int(schema.get("minItems", 1)) - len(fixed))
        if items is False:
            return fixed
        return fixed + [instance(items if isinstance(items, dict) else {}, policy, ctx, defs) for _ in range(count)]
    if kind in ("number", "integer"):
        return _number(schema, policy, ctx, integer=kind == "integer")
    if kind == "boolean":
        return False
    if kind == "null":
        return None
    text = FILLER_TEXT
    return text.ljust(int(schema.get("minLength", 0)), ".")


def parse_policy(arg: str | None) -> tuple[str, int]:
    """`first` | `random[:SEED]` | `keyword` -> (policy, seed); BackendSpecError on anything else."""
    name, _, seed_text = (arg or "").partition(":")
    name = name.strip().lower()
    known = "policy:first, policy:random[:SEED], policy:keyword, policy:oracle"
    if name not in POLICIES:
        raise BackendSpecError(f"unknown policy '{arg or ''}' (known: {known})")
    if seed_text and name != "random":
        raise BackendSpecError(f"policy '{name}' takes no argument, got '{arg}' (known: {known})")
    try:
        seed = int(seed_text) if seed_text else 0
    except ValueError:
        raise BackendSpecError(f"policy:random needs an integer seed, got '{seed_text}'") from None
    return name, seed


class PolicyBackend(Backend):
    """Answers from the request's JSON Schema alone (see the module docstring)."""

    name = "policy"
    default_arg = "first"
    description = (
        "No model: null policies policy:first, policy:random[:SEED], policy:keyword; "
        "policy:oracle answers as a perfect model would (ground truth)"
    )
    example = "policy:first"
    multimodal = False
    deterministic = True

    def __init__(self, arg: str | None = None, **options: Any) -> None:
        super().__init__(arg, **options)
        if options:
            raise BackendSpecError(f"policy takes no options, got: {', '.join(sorted(options))}")
        self.policy, self.seed = parse_policy(self.arg)
        self.answer_key: AnswerKey | None = None  # policy:oracle: attached by the runner per episode

    @property
    def wants_answer_key(self) -> bool:
        """Whether this backend answers from a planner's answer key (`policy:oracle`)."""
        return self.policy == "oracle"

    def attach_answer_key(self, key: AnswerKey | None) -> None:
        """The answer key of the episode about to run (None detaches it)."""
        self.answer_key = key

    def _key(self) -> AnswerKey:
        if self.answer_key is None:
            raise ModelError(f"{self.spec}: no answer key attached (the planner offers no oracle answers)")
        return self.answer_key

    @classmethod
    def status(cls, arg: str | None = None) -> BackendStatus:
        """Always ready: nothing to load or reach."""
        try:
            policy, _ = parse_policy(arg)
        except BackendSpecError as err:
            return BackendStatus(False, str(err))
        if policy == "oracle":
            return BackendStatus(True, "no model: the planner's oracle answers, from ground truth")
        return BackendStatus(True, "no model: answers from the request's JSON Schema")

    @property
    def can_score(self) -> bool:
        """Every null policy scores; the oracle does when its answer key does.

        Before an episode's key is attached (a planner checks its backend before the world exists) the
        oracle says it can: a key that cannot score refuses scoring requests with a `ModelError`.
        """
        if self.wants_answer_key and self.answer_key is not None:
            return self.answer_key.can_score
        return True

    def _rng(self, logged: dict[str, Any]) -> random.Random:
        # Seeded by the request itself: a correction turn (new messages) draws afresh, a rerun draws the same.
        digest = hashlib.sha256(json.dumps(logged, sort_keys=True).encode("utf-8")).digest()
        return random.Random(self.seed * 2**64 + int.from_bytes(digest[:8], "big"))

    def score(self, request: ScoreRequest) -> ScoreResult:
        """Scores by the policy: position, a seeded draw, shared words, or the answer key's (`oracle`)."""
        if self.wants_answer_key:
            return self._oracle_scores(request)
        ctx = _Context((Message("user", request.prefix),), self._rng(request.to_log()))
        task = words(ctx.task())
        values: list[float] = []
        for index, text in enumerate(request.continuations):
            if self.policy == "first":
                values.append(-float(index))
            elif self.policy == "random":
                values.append(round(ctx.rng.uniform(-10.0, 0.0), 6))
            else:
                values.append(float(len(task & words(text))))
        pairs = zip(values, request.continuations, strict=True)
        scores = tuple(ContinuationScore(v, max(1, len(words(t)))) for v, t in pairs)
        return ScoreResult(scores, 0.0, self.spec, {"policy": self.policy, "mode": "score"})

    def _oracle_scores(self, request: ScoreRequest) -> ScoreResult:
        key = self._key()
        if not key.can_score:
            raise ModelError(f"{self.spec}: this planner's oracle answers include no scores")
        values = key.scores(request)
        if len(values) != len(request.continuations):
            raise ModelError(f"{self.spec}: the answer key scored {len(values)} of {len(request.continuations)}")
        scores = tuple(ContinuationScore(float(v), 1) for v in values)
        return ScoreResult(scores, 0.0, self.spec, {"policy": self.policy, "mode": "score"})

    def chat(self, request: ChatRequest) -> ChatResult:
        """One answer built from `request.json_schema` (free text without one), or the answer key's (`oracle`)."""
        if self.wants_answer_key:
            text = self._key().answer(request)
            return ChatResult(text=text, latency_s=0.0, model=self.spec, meta={"policy": self.policy})
        rng = self._rng(request.to_log())
        ctx = _Context(request.messages, rng)
        schema = request.json_schema
        try:
            value = instance(schema, self.policy, ctx) if schema else FILLER_TEXT
        except (ValueError, TypeError, KeyError) as err:
            raise ModelError(f"{self.spec}: cannot answer this request's schema: {err}") from None
        text = value if isinstance(value, str) and not schema else json.dumps(value)
        return ChatResult(text=text, latency_s=0.0, model=self.spec, meta={"policy": self.policy})
