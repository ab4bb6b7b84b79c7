"""The `local:hf:DIR` path with a tiny randomly initialised GPT-2 and an offline byte tokenizer."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from llmnav.backends.base import ChatRequest, Image, Message, get_backend
from llmnav.backends.hf import transcript
from llmnav.backends.local import LocalBackend
from llmnav.errors import ModelUnavailableError

MESSAGES = (Message("system", "You drive a robot."), Message("user", "Where now?"))


@pytest.fixture(scope="module")
def tiny_gpt2(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 1-layer GPT-2 with random weights plus ByT5's byte tokenizer, saved like a downloaded model."""
    transformers = pytest.importorskip(
        "transformers", reason="optional extra llmnav[hf] (transformers + torch==2.13.0) not installed"
    )
    pytest.importorskip("torch", reason="optional extra llmnav[hf] needs torch==2.13.0 (CPU wheel)")
    directory = tmp_path_factory.mktemp("tiny-gpt2")
    tokenizer = transformers.ByT5Tokenizer()  # needs no download
    config = transformers.GPT2Config(
        vocab_size=len(tokenizer), n_positions=128, n_embd=32, n_layer=1, n_head=2,
        bos_token_id=tokenizer.eos_token_id, eos_token_id=tokenizer.eos_token_id,
    )  # fmt: skip
    transformers.GPT2LMHeadModel(config).save_pretrained(directory)
    tokenizer.save_pretrained(directory)
    return directory


def test_generates_from_local_directory(tiny_gpt2: Path) -> None:
    backend = get_backend(f"local:hf:{tiny_gpt2}")
    assert LocalBackend.status(f"hf:{tiny_gpt2}").ready
    result = backend.chat(ChatRequest(messages=MESSAGES, max_tokens=8, seed=0))
    assert result.meta["engine"] == "transformers" and result.meta["constrained"] is False
    assert 0 < (result.completion_tokens or 0) <= 8
    assert result.prompt_tokens == len(transcript(MESSAGES).encode()) + 1  # bytes + </s>
    assert result.model == tiny_gpt2.name
    again = backend.chat(ChatRequest(messages=MESSAGES, max_tokens=8, seed=0))
    assert again.text == result.text  # greedy: repeatable


def test_sampling_follows_the_seed(tiny_gpt2: Path) -> None:
    backend = get_backend(f"local:hf:{tiny_gpt2}")
    texts = [
        backend.chat(ChatRequest(messages=MESSAGES, max_tokens=12, temperature=1.0, seed=seed)).text
        for seed in (5, 5, 6)
    ]
    assert texts[0] == texts[1]
    assert texts[0] != texts[2]


def test_long_prompt_keeps_the_newest_tokens(tiny_gpt2: Path) -> None:
    backend = get_backend(f"local:hf:{tiny_gpt2}")
    long = (Message("user", "x" * 400), Message("user", "latest", (Image("AAAA"),)))
    result = backend.chat(ChatRequest(messages=long, max_tokens=4, seed=0))
    assert result.meta["truncated_prompt_tokens"] > 0
    assert result.meta["images_dropped"] == 1
    assert (result.prompt_tokens or 0) + 4 <= 128


def test_missing_directory_is_one_line(tmp_path: Path) -> None:
    with pytest.raises(ModelUnavailableError) as err:
        get_backend(f"local:hf:{tmp_path / 'distilgpt2'}").chat(ChatRequest(messages=MESSAGES))
    assert "\n" not in str(err.value) and "distilgpt2" in str(err.value)
    assert not LocalBackend.status(f"hf:{tmp_path}").ready


def test_missing_transformers_names_the_extra(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    (tmp_path / "config.json").write_text("{}")
    monkeypatch.setitem(sys.modules, "transformers", None)  # makes `import transformers` fail
    with pytest.raises(ModelUnavailableError) as err:
        get_backend(f"local:hf:{tmp_path}", threads=1).load()
    assert "llmnav[hf]" in str(err.value) and "\n" not in str(err.value)


def test_chat_template_is_used_when_the_tokenizer_has_one(tiny_gpt2: Path) -> None:
    engine = get_backend(f"local:hf:{tiny_gpt2}").load()
    tokenizer = engine._tokenizer  # type: ignore[attr-defined]
    assert engine.prompt_text(MESSAGES) == transcript(MESSAGES)  # type: ignore[attr-defined]
    tokenizer.chat_template = "{% for m in messages %}<{{ m.role }}>{{ m.content }}{% endfor %}<assistant>"
    try:
        text = engine.prompt_text(MESSAGES)  # type: ignore[attr-defined]
    finally:
        tokenizer.chat_template = None
    assert text == "<system>You drive a robot.<user>Where now?<assistant>"
