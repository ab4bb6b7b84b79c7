"""Backend spec strings are read in one place: who answers under each."""

import pytest

from llmnav.backends.base import answerer, parse_spec


@pytest.mark.parametrize(
    ("spec", "who"),
    [
        ("local", "model"),
        ("openai:qwen2.5@http://127.0.0.1:8080/v1", "model"),
        ("policy:first", "policy"),
        ("policy:random:7", "policy"),
        (" Policy:keyword ", "policy"),
        ("policy:oracle", "oracle"),
        ("policy:ORACLE:noisy", "oracle"),
        ("policy:oracles", "policy"),
    ],
)
def test_who_answers(spec: str, who: str) -> None:
    assert answerer(spec) == who


def test_a_spec_splits_at_its_first_colon() -> None:
    assert parse_spec("OpenAI:m@http://h:1/v1") == ("openai", "m@http://h:1/v1")
    assert parse_spec("local") == ("local", None)
