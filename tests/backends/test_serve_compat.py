"""The request and reply changes of `llmnav serve`'s front on the cases a live server rarely shows.

The live cases (through the `openai` SDK) are in test_serve_sdk.py; these feed llama.cpp-shaped
replies to the pure functions: several prompts, prompts given as token ids, unknown flags in errors.
"""

from __future__ import annotations

import json
from typing import Any

from llmnav.serve.compat import Adapted, Refusal, adapt_request, true_error

NAMES = ("local", "gpt-4o-mini")


def _item(token: str, logprob: float, *alternatives: tuple[str, float]) -> dict[str, Any]:
    top = [{"id": i, "token": t, "logprob": lp} for i, (t, lp) in enumerate(alternatives)]
    return {"id": 7, "token": token, "logprob": logprob, "top_logprobs": top}


def _completions(body: dict[str, Any]) -> Adapted:
    adapted = adapt_request("POST", "/v1/completions", json.dumps(body).encode(), NAMES)
    assert isinstance(adapted, Adapted)
    return adapted


def test_each_prompt_offsets_its_own_choice() -> None:
    adapted = _completions({"model": "local", "prompt": ["Hi", "Hello there"], "logprobs": 1})
    reply = {
        "choices": [
            {"index": 1, "text": " you", "logprobs": {"content": [_item(" you", -0.5, (" you", -0.5))]}},
            {"index": 0, "text": "!!", "logprobs": {"content": [_item("!", -1.0), _item("!", -2.0)]}},
        ]
    }
    second, first = adapted.reply(reply)["choices"]
    assert second["logprobs"]["text_offset"] == [len("Hello there")]
    assert first["logprobs"]["text_offset"] == [2, 3] and first["logprobs"]["tokens"] == ["!", "!"]
    assert "content" in first["logprobs"]  # llama.cpp's own field stays for its clients


def test_token_id_prompts_count_offsets_from_the_completion() -> None:
    adapted = _completions({"prompt": [1, 2, 3], "logprobs": 2})
    reply = {"choices": [{"index": 0, "logprobs": {"content": [_item("a", -0.1), _item("bc", -0.2)]}}]}
    assert adapted.reply(reply)["choices"][0]["logprobs"]["text_offset"] == [0, 1]


def test_alternatives_beyond_n_are_dropped_and_the_chosen_kept() -> None:
    adapted = _completions({"model": "gpt-4o-mini", "prompt": "x", "logprobs": 1})
    assert json.loads(adapted.body)["logprobs"] == 1
    content = [_item(" b", -2.0, (" a", -0.5), (" b", -2.0), (" c", -3.0))]  # sampled, not the likeliest
    top = adapted.reply({"choices": [{"index": 0, "logprobs": {"content": content}}]})["choices"][0]["logprobs"]
    assert top["top_logprobs"] == [{" a": -0.5, " b": -2.0}]


def test_requests_without_logprobs_or_model_pass_unchanged() -> None:
    body = json.dumps({"prompt": "x", "max_tokens": 2}).encode()
    adapted = adapt_request("POST", "/v1/completions", body, NAMES)
    assert isinstance(adapted, Adapted) and adapted.body == body and not adapted.changes_replies
    assert isinstance(adapt_request("POST", "/completions", b'{"model": "other"}', NAMES), Refusal)
    assert isinstance(adapt_request("POST", "/v1/completions", b'{"model": "other"}', ()), Adapted)  # no names
    assert isinstance(adapt_request("POST", "/tokenize", b'{"model": "other"}', NAMES), Adapted)  # not OpenAI's


def test_responses_format_kinds() -> None:
    def adapt(spec: Any) -> Adapted | Refusal:
        body = json.dumps({"model": "local", "input": "x", "text": {"format": spec}}).encode()
        return adapt_request("POST", "/v1/responses", body, NAMES)

    as_object = adapt({"type": "json_object"})
    assert isinstance(as_object, Adapted) and json.loads(as_object.body)["response_format"] == {"type": "json_object"}
    plain = adapt({"type": "text"})
    assert isinstance(plain, Adapted) and "response_format" not in json.loads(plain.body)
    refused = adapt({"type": "xml"})
    assert isinstance(refused, Refusal) and refused.status == 400 and "'xml'" in refused.body["error"]["message"]


def test_error_hints_name_no_flag_of_llamacpps() -> None:
    known = true_error(
        {"error": {"code": 501, "message": "This server does not support reranking. Start it with `--reranking`"}}
    )
    assert known["error"]["message"].startswith("This server does not support reranking: llmnav serve")
    unknown = true_error({"error": {"message": "No frobnication. Start it with `--frob`."}})
    assert unknown["error"]["message"] == "No frobnication: llmnav serve has no option to turn it on"
    untouched = {"error": {"message": "image input is not supported - hint: mmproj"}}
    assert true_error(json.loads(json.dumps(untouched))) == untouched  # the image refusal backends recognise
