"""Scoring a continuation exactly with llama.cpp: its canonical tokens, forced by a grammar, read back.

Shared by the in-process engine (`local`) and llama.cpp's HTTP server (`openai` against `llama-server`
or `llmnav serve`): tokenise prefix + continuation, take the tokens after the prefix's own, force exactly
those with an llguidance grammar, and sum the log-probabilities llama.cpp reports for them (taken from the
logits before grammar and sampler). The ids that come back must be the ids sent.
"""

from __future__ import annotations

from typing import Any

from llmnav.backends.reply import logprob, obj, seq, token_ids
from llmnav.errors import ModelError, one_line


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


def forced_logprob(reply: Any, tail: list[int], text: str) -> float:
    """The summed log-probability of the forced tokens; `ModelError` unless they came back as sent."""
    if not isinstance(reply, dict) or "error" in reply:
        message = reply.get("error") if isinstance(reply, dict) else reply
        raise ModelError(f"the model failed to score {text!r}: {one_line(str(message))}")
    where = f"scoring {text!r}: choices[0].logprobs.content"
    choices = seq(reply.get("choices"), f"scoring {text!r}: choices")
    first = obj(choices[0], f"scoring {text!r}: choices[0]") if choices else {}
    content = seq(obj(first.get("logprobs"), f"scoring {text!r}: choices[0].logprobs").get("content"), where)
    if not content:
        raise ModelError(f"the scoring reply for {text!r} has no token log-probabilities")
    items = [obj(item, f"{where}[{i}]") for i, item in enumerate(content)]
    ids = token_ids([item.get("id") for item in items], f"{where}[].id")
    total = sum(logprob(item.get("logprob"), f"{where}[{i}].logprob") for i, item in enumerate(items))
    if ids != tail:
        raise ModelError(f"scoring {text!r}: the model returned tokens {ids}, not the forced {tail}")
    return total


def forced_request(prefix: list[int], tail: list[int]) -> dict[str, Any]:
    """The completion request that scores `tail` after `prefix` (prompt as ids, kept in the prompt cache)."""
    return {
        "prompt": prefix,
        "max_tokens": len(tail),
        "logprobs": 1,
        "temperature": 0.0,
        "cache_prompt": True,
        "grammar": forced_tokens_grammar(tail),
    }
