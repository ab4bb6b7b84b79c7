"""Scoring a continuation exactly with llama.cpp: its canonical tokens, forced by a grammar, read back.

Shared by the in-process engine (`local`) and llama.cpp's HTTP server (`openai` against `llama-server`
or `llmnav serve`): tokenise prefix + continuation (both NFC-normalised, so a decomposed `cafe\u0301`
scores as `café`), take the tokens after the prefix's own, force exactly those with an llguidance
grammar, and sum the log-probabilities llama.cpp reports for them (taken from the logits before grammar
and sampler). The ids that come back must be the ids sent.

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


def score_continuation(prefix_text: str, text: str, tokenize: Tokenize, complete: Complete) -> ContinuationScore:
    """The log-probability [nats] of `text` after `prefix_text`, over its canonical tokens.

    One forced request when every token comes back; token by token when the server held some back
    (byte-fallback tokens, see the module docstring).
    """
    prefix = tokenize(normalised(prefix_text))
    tail = continuation_tokens(prefix, tokenize(normalised(prefix_text + text)), text)
    ids, total = _summed(_reported(complete(forced_request(prefix, tail)), text), text)
    if ids == tail:
        return ContinuationScore(total, len(tail))
    if not ids or ids[-1] != tail[-1] or not set(ids) <= set(tail):  # not merely some held back
        raise ModelError(f"scoring {text!r}: the model returned tokens {ids}, not the forced {tail}")
    total = sum(_one_token(prefix + tail[:i], token, text, tokenize, complete) for i, token in enumerate(tail))
    return ContinuationScore(total, len(tail))


def _one_token(before: list[int], token: int, text: str, tokenize: Tokenize, complete: Complete) -> float:
    """The log-probability of `token` right after `before`: forced alone, else read among the alternatives."""
    ids, total = _summed(_reported(complete(forced_request(before, [token])), text), text)
    if ids == [token]:
        return total
    if ids:
        raise ModelError(f"scoring {text!r}: the model returned tokens {ids}, not the forced [{token}]")
    newline = tokenize("\n")[-1]  # a token ending a character: its position is always reported
    for count in (FEW_ALTERNATIVES, ALL_ALTERNATIVES):
        items = _reported(complete(forced_request(before, [newline], count)), text)
        if len(items) != 1:
            raise ModelError(f"scoring {text!r}: {len(items)} entries for one forced newline")
        where = f"scoring {text!r}: choices[0].logprobs.content[0].top_logprobs"
        for i, other in enumerate(seq(items[0].get("top_logprobs"), where)):
            entry = obj(other, f"{where}[{i}]")
            if entry.get("id") == token:
                return logprob(entry.get("logprob"), f"{where}[{i}].logprob")
    raise ModelError(f"scoring {text!r}: the model reported no log-probability for token {token}")
