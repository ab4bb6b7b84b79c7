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
