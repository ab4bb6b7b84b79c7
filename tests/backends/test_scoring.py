"""Scoring continuations: the canonical tail, forced tokens, PMI with the real local model, policies, replay."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from llmnav.backends.base import get_backend
from llmnav.backends.forced import continuation_tokens, forced_logprob, forced_request, forced_tokens_grammar
from llmnav.backends.local import LocalBackend
from llmnav.backends.memo import ScoreMemo
from llmnav.backends.policy import PolicyBackend
from llmnav.backends.replay import ReplayBackend, write_script
from llmnav.core.chat import ContinuationScore, ScoreRequest
from llmnav.errors import ModelError, ReplayDivergenceError
from llmnav.runs.runlog import RunLog

LABELS = ("oil barrel", "stairs", "table", "fire extinguisher", "cardboard box")


@pytest.fixture(scope="module")
def backend() -> LocalBackend:
    b = LocalBackend()
    b.load()
    return b


# --- the canonical tail -----------------------------------------------------------------------
def test_continuation_tokens_are_the_tail_after_the_prefix() -> None:
    assert continuation_tokens([1, 2, 3], [1, 2, 3, 7, 8], " x") == [7, 8]


def test_continuation_tokens_refuse_a_prefix_that_retokenises() -> None:
    with pytest.raises(ModelError, match="tokenises differently"):
        continuation_tokens([1, 2, 3], [1, 2, 9, 8], " x")
    with pytest.raises(ModelError, match="has no tokens"):
        continuation_tokens([1, 2], [1, 2], "")


def test_forced_grammar_names_every_id_in_order() -> None:
    assert forced_tokens_grammar([11, 5, 300]) == "%llguidance {}\nstart: <[11]> <[5]> <[300]>"


def _forced(backend: LocalBackend, prefix: str, text: str) -> tuple[list[int], list[dict[str, Any]]]:
    """The canonical tail of `text` after `prefix` and the engine's reply items for it, forced as sent."""
    engine: Any = backend.load()
    ids = engine.tokenize(prefix)
    tail = continuation_tokens(ids, engine.tokenize(prefix + text), text)
    reply = engine._server.handle_completions(forced_request(ids, tail))
    return tail, reply["choices"][0]["logprobs"]["content"]


def test_canonical_tail_spells_the_continuation_in_whole_words(backend: LocalBackend) -> None:
    """With the real tokeniser: the forced tail reads back as the text, its first token carrying the space.

    (A plain string grammar lets greedy decoding start with a lone " ", a split the model never writes.)
    """
    _, items = _forced(backend, "Task: find it\nThe robot drives to the", " fire extinguisher")
    pieces = [item["token"] for item in items]
    assert "".join(pieces) == " fire extinguisher"
    assert pieces[0] == " fire"


# --- forced tokens come back as sent -----------------------------------------------------------
def test_forced_tokens_come_back_as_sent(backend: LocalBackend) -> None:
    tail, items = _forced(backend, "Task: Go to the stairs\nThe robot drives to the", " stairs")
    assert [item["id"] for item in items] == tail


def test_a_reply_with_other_tokens_is_a_model_error() -> None:
    reply = {"choices": [{"logprobs": {"content": [{"id": 5, "logprob": -0.1}, {"id": 6, "logprob": -1.0}]}}]}
    assert forced_logprob(reply, [5, 6], " x") == pytest.approx(-1.1)
    with pytest.raises(ModelError, match="not the forced"):
        forced_logprob(reply, [5, 7], " x")
    with pytest.raises(ModelError, match="no token log-probabilities"):
        forced_logprob({"choices": [{}]}, [5], " x")


def test_scores_follow_the_chain_rule(backend: LocalBackend) -> None:
    """log P(a b | p) = log P(a | p) + log P(b | p a): the forced scores are exact, not a sampler's guess."""
    prefix = "Task: Find the fire extinguisher\nThe robot drives to the"
    both = backend.score(ScoreRequest(prefix, (" fire extinguisher",))).scores[0]
    first = backend.score(ScoreRequest(prefix, (" fire",))).scores[0]
    second = backend.score(ScoreRequest(prefix + " fire", (" extinguisher",))).scores[0]
    assert both.tokens == first.tokens + second.tokens
    assert both.logprob == pytest.approx(first.logprob + second.logprob, abs=0.02)
    assert both.logprob < 0


class _TinyServer:
    """A /completions stand-in over a made-up model: log P(token | context) is a fixed function of both.

    It answers forced requests (the grammar's ids, each with its log-probability) and reports the top
    `logprobs` alternatives of the first position over a 20-token vocabulary, as llama.cpp does.
    """

    VOCAB = range(1, 21)

    def __init__(self) -> None:
        self.requests: list[dict[str, Any]] = []

    @staticmethod
    def logprob(context: list[int], token: int) -> float:
        return -0.1 - ((sum(context) * 7 + token * 13) % 97) / 10

    def __call__(self, body: dict[str, Any]) -> dict[str, Any]:
        self.requests.append(body)
        forced = [int(part[2:-2]) for part in body["grammar"].split("start: ", 1)[1].split()]
        context, items = list(body["prompt"]), []
        for token in forced:
            ranked = sorted(self.VOCAB, key=lambda t: -self.logprob(context, t))[: body["logprobs"]]
            top = [{"id": t, "logprob": self.logprob(context, t)} for t in ranked]
            items.append({"id": token, "logprob": self.logprob(context, token), "top_logprobs": top})
            context.append(token)
        return {"choices": [{"logprobs": {"content": items}}]}


def test_continuations_share_the_positions_they_pass_through() -> None:
    """Each position is evaluated once for every continuation through it, and every sum is still exact."""
    from llmnav.backends import forced

    words = {" a": [2, 3], " b": [2, 4], " c": [2, 5], " d": [2, 6, 7], " e": [8, 9]}  # each text's tail
    known = {"p": [1], "\n": [19]} | {"p" + text: [1, *tail] for text, tail in words.items()}
    tokenize = known.__getitem__
    server = _TinyServer()
    texts = (" a", " b", " c", " d", " e")
    scores = forced.score_continuations("p", texts, tokenize, server)
    for text, score in zip(texts, scores, strict=True):
        tail = words[text]
        exact = sum(server.logprob([1, *tail[:i]], token) for i, token in enumerate(tail))
        assert score.tokens == len(tail) and score.logprob == pytest.approx(exact, abs=1e-9)
    # " e" and the shared 2 are forced (two branches at the root: under BRANCH_MIN); after 2, four
    # branches are read from one request's alternatives, and only " d"'s last token is forced alone.
    prompts = [body["prompt"] for body in server.requests]
    assert sorted(prompts) == sorted([[1], [1], [1, 2], [1, 2, 6]])
    assert [body["logprobs"] for body in server.requests if body["prompt"] == [1, 2]] == [forced.BRANCH_ALTERNATIVES]
    # A next token missing from the alternatives is forced on its own.
    server = _TinyServer()
    few = forced.BRANCH_ALTERNATIVES
    try:
        forced.BRANCH_ALTERNATIVES = 1
        again = forced.score_continuations("p", texts, tokenize, server)
    finally:
        forced.BRANCH_ALTERNATIVES = few
    assert [s.logprob for s in again] == pytest.approx([s.logprob for s in scores], abs=1e-9)
    assert len(server.requests) > 4


def test_a_repeated_pair_comes_from_the_memo_with_the_same_score(backend: LocalBackend) -> None:
    """Only the continuations not scored before reach the engine; remembered ones return their first score."""
    prefix = "Task: Find the mop\nThe robot drives to the"
    engine: Any = backend.load()
    asked: list[tuple[str, ...]] = []
    real = engine.score
    engine.score = lambda request: asked.append(request.continuations) or real(request)
    try:
        first = backend.score(ScoreRequest(prefix, (" mop", " bucket")))
        again = backend.score(ScoreRequest(prefix, (" bucket", " broom", " mop", " broom")))
    finally:
        del engine.score
    assert asked == [(" mop", " bucket"), (" broom",)]
    assert again.meta["memo_hits"] == 2 and first.meta["memo_hits"] == 0
    assert again.scores[0] == first.scores[1] and again.scores[2] == first.scores[0]
    assert again.scores[1] == again.scores[3]
    assert again.model == first.model == engine.model_name


def test_the_memo_forgets_the_least_recently_used_pair() -> None:
    memo = ScoreMemo(entries=2)
    memo.put("p", " a", ContinuationScore(-1.0, 1))
    memo.put("p", " b", ContinuationScore(-2.0, 1))
    assert memo.get("p", " a") == ContinuationScore(-1.0, 1)  # now the most recently used
    memo.put("q", " a", ContinuationScore(-3.0, 1))
    assert memo.get("p", " b") is None and memo.get("p", " a") is not None and len(memo) == 2


def test_pmi_picks_the_named_object_with_the_real_model(backend: LocalBackend) -> None:
    """Domain-conditional PMI on a fixed prompt: the task's object wins, the raw prior does not decide."""
    template = "A mobile robot carries out the user's task.\nTask: {task}\nThe robot drives to the"
    conts = tuple(" " + label for label in LABELS)
    with_task = backend.score(ScoreRequest(template.format(task="Find the fire extinguisher"), conts)).scores
    free = backend.score(ScoreRequest(template.format(task="N/A"), conts)).scores
    pmi = {label: a.logprob - b.logprob for label, a, b in zip(LABELS, with_task, free, strict=True)}
    assert max(pmi, key=pmi.__getitem__) == "fire extinguisher", pmi
    assert pmi["fire extinguisher"] > 5.0 + max(v for k, v in pmi.items() if k != "fire extinguisher"), pmi


# --- policies score as their policy -------------------------------------------------------------
def test_policy_scores() -> None:
    request = ScoreRequest("Task: Go to the oil barrel\nThe robot drives to the", tuple(" " + x for x in LABELS))
    first = PolicyBackend("first").score(request).scores
    assert [s.logprob for s in first] == [0.0, -1.0, -2.0, -3.0, -4.0]
    keyword = PolicyBackend("keyword").score(request).scores
    assert [s.logprob for s in keyword] == [2.0, 0.0, 0.0, 0.0, 0.0]  # "oil" and "barrel"
    one = PolicyBackend("random:3").score(request).scores
    assert one == PolicyBackend("random:3").score(request).scores  # seeded by the request
    assert one != PolicyBackend("random:4").score(request).scores
    assert all(-10.0 <= s.logprob <= 0.0 for s in one)


def test_every_policy_and_local_can_score_and_http_backends_do_not_claim_it() -> None:
    assert PolicyBackend("first").can_score and LocalBackend().can_score
    assert not get_backend("ollama:m").can_score
    with pytest.raises(ModelError, match="cannot score"):
        get_backend("ollama:m").score(ScoreRequest("p", (" x",)))


# --- replay ------------------------------------------------------------------------------------
def _recorded(tmp_path: Path, request: ScoreRequest) -> Path:
    result = PolicyBackend("random:1").score(request)
    with RunLog(tmp_path / "rec", {"modality": "text"}) as log:
        log.event("llm_call", step=1, purpose="score", request=request.to_log(), reply=result.to_log())
    return tmp_path / "rec"


def test_replay_returns_recorded_scores_exactly(tmp_path: Path) -> None:
    request = ScoreRequest("Task: x\nThe robot drives to the", (" table", " stairs"))
    original = PolicyBackend("random:1").score(request).scores
    replay = ReplayBackend(str(_recorded(tmp_path, request)))
    assert replay.can_score
    assert replay.score(request).scores == original


def test_strict_replay_refuses_other_continuations(tmp_path: Path) -> None:
    request = ScoreRequest("Task: x\nThe robot drives to the", (" table", " stairs"))
    replay = ReplayBackend(str(_recorded(tmp_path, request)))
    with pytest.raises(ReplayDivergenceError):
        replay.score(ScoreRequest("Task: x\nThe robot drives to the", (" table", " window")))


def test_a_generation_recording_cannot_score(tmp_path: Path) -> None:
    spec = write_script(tmp_path / "s", ['{"option": 1}'])
    assert not ReplayBackend(spec).can_score
    lines = [json.loads(x) for x in (tmp_path / "s" / "run.jsonl").read_text().splitlines()]
    assert all("continuations" not in (e.get("request") or {}) for e in lines)
