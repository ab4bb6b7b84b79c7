"""Scoring a continuation exactly with llama.cpp: its canonical tokens, forced by a grammar, read back.

Shared by the in-process engine (`local`) and llama.cpp's HTTP server (`openai` against `llama-server`
or `llmnav serve`): tokenise prefix + continuation (both NFC-normalised, so a decomposed `cafe\u0301`
scores as `café`), take the tokens after the prefix's own, force exactly those with an llguidance
grammar, and sum the log-probabilities llama.cpp reports for them (taken from the logits before grammar
and sampler). The ids that come back must be the ids sent.

A request's continuations share work: their tails form a token tree, and a position several of them
pass through is evaluated once (`score_continuations`). Where many part, one request reads every next
token from the position's reported alternatives, which are the numbers a forced token reports.

Byte-fallback tokens: a character outside the vocabulary (most of Chinese, Japanese, Arabic, emoji) is
spelt as several tokens of raw bytes. llama.cpp holds back a token whose text ends inside a character
and never reports its log-probability, only that of the token completing the character. Such a
continuation is scored token by token instead: each token forced alone after the tokens before it,
and a held-back one read from the alternatives reported for that position while a newline is forced
there (the alternatives are the same distribution, taken before the grammar).
"""

from __future__ import annotations

import unicodedata
from collections.abc import Callable
from typing import Any

from llmnav.backends.reply import logprob, obj, seq, token_ids
from llmnav.core.chat import ContinuationScore
from llmnav.errors import ModelError, one_line

# [alternatives] asked for a held-back token's position: first a few, then the whole vocabulary (the
# server caps the count at its vocabulary size; 2**20 exceeds every vocabulary in use).
FEW_ALTERNATIVES = 256
ALL_ALTERNATIVES = 1 << 20
# Where at least BRANCH_MIN continuations part, their next tokens are read from one request of
# BRANCH_ALTERNATIVES alternatives (as cheap as 256, and about as dear as two forced tokens, so two
# branches are forced instead); a next token not among them is forced.
BRANCH_ALTERNATIVES = 4096
BRANCH_MIN = 3

Complete = Callable[[dict[str, Any]], Any]  # a /completions request body → the reply's JSON
Tokenize = Callable[[str], list[int]]  # text → the model's token ids as a prompt


def normalised(text: str) -> str:
    """`text` in Unicode NFC: one spelling of each character, the one tokenisers were trained on."""
    return unicodedata.normalize("NFC", text)


def continuation_tokens(prefix: list[int], whole: list[int], text: str) -> list[int]:
    """The canonical tokens of a continuation: those of prefix + continuation after the prefix's own.

    `ModelError` when the prefix's tokens are not a prefix of the whole (the continuation would then
    re-tokenise the prefix's end) or the continuation adds no token.
    """
    if whole[: len(prefix)] != prefix:
        raise ModelError(f"scoring: the prompt tokenises differently when followed by {text!r}")
    tail = whole[len(prefix) :]
    if not tail:
        raise ModelError(f"scoring: the continuation {text!r} has no tokens")
    return tail


def forced_tokens_grammar(tokens: list[int]) -> str:
    """An llguidance grammar that allows exactly these token ids, in order.

    A plain string grammar would let greedy decoding split the text in odd ways (" " then "fire"), and
    each odd split has a far lower log-probability than the canonical one; GBNF's `<[id]>` does not
    work in this engine build, llguidance's does.
    """
    return "%llguidance {}\nstart: " + " ".join(f"<[{token}]>" for token in tokens)


def forced_request(prefix: list[int], tail: list[int], alternatives: int = 1) -> dict[str, Any]:
    """The completion request that scores `tail` after `prefix` (prompt as ids, kept in the prompt cache)."""
    return {
        "prompt": prefix,
        "max_tokens": len(tail),
        "logprobs": alternatives,
        "temperature": 0.0,
        "cache_prompt": True,
        "grammar": forced_tokens_grammar(tail),
    }


def _reported(reply: Any, text: str) -> list[dict[str, Any]]:
    """The per-token entries of a completion reply (none when the server reported none)."""
    if not isinstance(reply, dict) or "error" in reply:
        message = reply.get("error") if isinstance(reply, dict) else reply
        raise ModelError(f"the model failed to score {text!r}: {one_line(str(message))}")
    choices = seq(reply.get("choices"), f"scoring {text!r}: choices")
    first = obj(choices[0], f"scoring {text!r}: choices[0]") if choices else {}
    logprobs = first.get("logprobs")
    if logprobs is None:
        return []
    where = f"scoring {text!r}: choices[0].logprobs.content"
    content = obj(logprobs, f"scoring {text!r}: choices[0].logprobs").get("content")
    return [obj(item, f"{where}[{i}]") for i, item in enumerate(seq(content, where) if content is not None else [])]


def _summed(items: list[dict[str, Any]], text: str) -> tuple[list[int], float]:
    where = f"scoring {text!r}: choices[0].logprobs.content"
    ids = token_ids([item.get("id") for item in items], f"{where}[].id") if items else []
    return ids, sum(logprob(item.get("logprob"), f"{where}[{i}].logprob") for i, item in enumerate(items))


def forced_logprob(reply: Any, tail: list[int], text: str) -> float:
    """The summed log-probability of the forced tokens; `ModelError` unless they came back as sent."""
    items = _reported(reply, text)
    if not items:
        raise ModelError(f"the scoring reply for {text!r} has no token log-probabilities")
    ids, total = _summed(items, text)
    if ids != tail:
        raise ModelError(f"scoring {text!r}: the model returned tokens {ids}, not the forced {tail}")
    return total


def score_continuations(
    prefix_text: str, texts: tuple[str, ...], tokenize: Tokenize, complete: Complete
) -> list[ContinuationScore]:
    """The log-probability [nats] of each of `texts` after `prefix_text`, over its canonical tokens.

    The tails form a token tree, and each position is evaluated once for all the tails that share it
    (`_walk`): a menu of " the bed", " the sofa", " the oil barrel" forces " the" once, reads the next
    token of all three from one distribution, and forces " barrel" alone.
    """
    prefix = tokenize(normalised(prefix_text))
    tails = [continuation_tokens(prefix, tokenize(normalised(prefix_text + text)), text) for text in texts]
    totals = [0.0] * len(texts)
    _walk(prefix, tails, list(range(len(texts))), 0, texts, totals, tokenize, complete)
    return [ContinuationScore(total, len(tail)) for total, tail in zip(totals, tails, strict=True)]


def _walk(
    prefix: list[int],
    tails: list[list[int]],
    members: list[int],
    depth: int,
    texts: tuple[str, ...],
    totals: list[float],
    tokenize: Tokenize,
    complete: Complete,
) -> None:
    """Add to `totals` the log-probabilities of `members`' tails from position `depth` on.

    The members share their first `depth` tokens. Where at least `BRANCH_MIN` next tokens part, one
    request reads all of them from the position's distribution (its alternatives, the same numbers a
    forced token reports); elsewhere each branch forces its members' common run of tokens in one request.
    """
    before = prefix + tails[members[0]][:depth]
    groups: dict[int, list[int]] = {}
    for index in members:
        groups.setdefault(tails[index][depth], []).append(index)
    read = _alternatives(before, texts[members[0]], tokenize, complete) if len(groups) >= BRANCH_MIN else {}
    for token, group in groups.items():
        if token in read:
            run = [token]
            value = read[token]
        else:
            run = _common_run([tails[index][depth:] for index in group])
            value = _forced_run(before, run, texts[group[0]], tokenize, complete)
        for index in group:
            totals[index] += value
        rest = [index for index in group if len(tails[index]) > depth + len(run)]
        if rest:
            _walk(prefix, tails, rest, depth + len(run), texts, totals, tokenize, complete)


def _common_run(tails: list[list[int]]) -> list[int]:
    """The longest run of tokens every tail begins with (at least the first, which they share)."""
    run = tails[0]
    for tail in tails[1:]:
        length = 0
        while length < min(len(run), len(tail)) and run[length] == tail[length]:
            length += 1
        run = run[:length]
    return run


def _forced_run(before: list[int], run: list[int], text: str, tokenize: Tokenize, complete: Complete) -> float:
    """The summed log-probability of `run` after `before`: forced in one request, else token by token.

    Token by token only when the server held some tokens back (byte-fallback tokens, see the module
    docstring); any other difference between the ids sent and those returned is a `ModelError`.
    """
    ids, total = _summed(_reported(complete(forced_request(before, run)), text), text)
    if ids == run:
        return total
    if not ids or ids[-1] != run[-1] or not set(ids) <= set(run):  # not merely some held back
        raise ModelError(f"scoring {text!r}: the model returned tokens {ids}, not the forced {run}")
    return sum(_one_token(before + run[:i], token, text, tokenize, complete) for i, token in enumerate(run))


def _alternatives(before: list[int], text: str, tokenize: Tokenize, complete: Complete) -> dict[int, float]:
    """The log-probabilities of the `BRANCH_ALTERNATIVES` likeliest tokens after `before`, by token id.

    Read while a newline is forced (a token ending a character, so its position is always reported).
    """
    where = f"scoring {text!r}: top_logprobs"
    entries = _top(before, BRANCH_ALTERNATIVES, text, tokenize, complete)
    if not entries:  # a server that reports none: every branch is forced
        return {}
    ids = token_ids([entry.get("id") for entry in entries], f"{where}[].id")
    return {
        token: logprob(entry.get("logprob"), f"{where}[{i}].logprob")
        for i, (token, entry) in enumerate(zip(ids, entries, strict=True))
    }


def _top(before: list[int], count: int, text: str, tokenize: Tokenize, complete: Complete) -> list[dict[str, Any]]:
    """The `count` likeliest next tokens after `before` as the server reports them (id, logprob)."""
    newline = tokenize("\n")[-1]
    items = _reported(complete(forced_request(before, [newline], count)), text)
    if len(items) != 1:
        raise ModelError(f"scoring {text!r}: {len(items)} entries for one forced newline")
    where = f"scoring {text!r}: choices[0].logprobs.content[0].top_logprobs"
    return [obj(other, f"{where}[{i}]") for i, other in enumerate(seq(items[0].get("top_logprobs"), where))]


def _one_token(before: list[int], token: int, text: str, tokenize: Tokenize, complete: Complete) -> float:
    """The log-probability of `token` right after `before`: forced alone, else read among the alternatives."""
    ids, total = _summed(_reported(complete(forced_request(before, [token])), text), text)
    if ids == [token]:
        return total
    if ids:
        raise ModelError(f"scoring {text!r}: the model returned tokens {ids}, not the forced [{token}]")
    where = f"scoring {text!r}: top_logprobs"
    for count in (FEW_ALTERNATIVES, ALL_ALTERNATIVES):
        for i, entry in enumerate(_top(before, count, text, tokenize, complete)):
            if entry.get("id") == token:
                return logprob(entry.get("logprob"), f"{where}[{i}].logprob")
    raise ModelError(f"scoring {text!r}: the model reported no log-probability for token {token}")
