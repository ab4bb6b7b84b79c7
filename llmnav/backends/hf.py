"""The `local:hf:DIR` engine: a Hugging Face transformers causal LM loaded from a local directory.

Optional (`pip install 'llmnav[hf]'`, i.e. transformers + the CPU wheel of torch 2.13.0). Nothing is
downloaded at run time (`local_files_only=True`): a missing package or missing weights is one
`ModelUnavailableError` line. There is no grammar here, so the answer is free text that the guard
downstream extracts, repairs or rejects. The prompt is the tokenizer's chat template when it has one,
else a plain transcript with one role prefix per message.
"""

from __future__ import annotations

import time
from importlib.util import find_spec
from pathlib import Path
from typing import Any

from llmnav.backends.base import (
    BackendStatus,
    ChatRequest,
    ChatResult,
    ContinuationScore,
    Message,
    ScoreRequest,
    ScoreResult,
)
from llmnav.backends.forced import continuation_tokens, normalised
from llmnav.backends.reply import continuation_score
from llmnav.errors import ModelError, ModelUnavailableError, one_line

HF_INSTALL_HINT = "pip install 'llmnav[hf]' (transformers and torch==2.13.0, the CPU wheel)"
ROLE_PREFIX = {"system": "System", "user": "User", "assistant": "Assistant"}


def hf_directory(arg: str) -> Path:
    """The model directory named in `local:hf:DIR`, checked to hold a transformers config."""
    if not arg:
        raise ModelUnavailableError("local:hf needs a model directory, e.g. local:hf:./models/distilgpt2")
    directory = Path(arg).expanduser()
    if not (directory / "config.json").is_file():
        raise ModelUnavailableError(
            f"no transformers model in {directory} (expected config.json and weights; nothing is downloaded)"
        )
    return directory


def _import_stack() -> tuple[Any, Any]:
    try:
        # deferred: torch and transformers are the optional 'hf' extra (seconds to import)
        import torch
        import transformers
    except ImportError:
        raise ModelUnavailableError(f"local:hf needs transformers and torch: {HF_INSTALL_HINT}") from None
    return torch, transformers


def hf_status(arg: str) -> BackendStatus:
    """Directory found and transformers importable (without importing torch: that alone takes seconds)."""
    try:
        directory = hf_directory(arg)
    except ModelUnavailableError as err:
        return BackendStatus(False, str(err))
    missing = [name for name in ("transformers", "torch") if find_spec(name) is None]
    if missing:
        return BackendStatus(False, f"local:hf needs {' and '.join(missing)}: {HF_INSTALL_HINT}")
    return BackendStatus(True, f"{directory} (transformers)")


def transcript(messages: tuple[Message, ...]) -> str:
    """A plain role-prefixed transcript ending with the assistant's cue, for tokenizers without a template."""
    lines = [f"{ROLE_PREFIX[m.role]}: {m.text}" for m in messages]
    return "\n".join([*lines, f"{ROLE_PREFIX['assistant']}:"])


class HFEngine:
    """A causal LM and its tokenizer, loaded once from a local directory."""

    def __init__(self, directory: Path, *, threads: int) -> None:
        torch, transformers = _import_stack()
        torch.set_num_threads(threads)
        try:
            self._tokenizer = transformers.AutoTokenizer.from_pretrained(directory, local_files_only=True)
            self._model = transformers.AutoModelForCausalLM.from_pretrained(directory, local_files_only=True)
        except (OSError, ValueError) as err:
            raise ModelUnavailableError(f"could not load a causal LM from {directory}: {one_line(err)}") from None
        self._model.eval()
        self._torch = torch
        self.model_name = directory.name
        # Longest input the model accepts [tokens]; GPT-2 style configs call it n_positions.
        config = self._model.config
        self.max_positions: int | None = getattr(config, "max_position_embeddings", None) or getattr(
            config, "n_positions", None
        )

    def prompt_text(self, messages: tuple[Message, ...]) -> str:
        """The prompt string: the chat template if the tokenizer has one, else `transcript`."""
        if getattr(self._tokenizer, "chat_template", None):
            chat = [{"role": m.role, "content": m.text} for m in messages]
            text: str = self._tokenizer.apply_chat_template(chat, tokenize=False, add_generation_prompt=True)
            return text
        return transcript(messages)

    def score(self, request: ScoreRequest) -> ScoreResult:
        """Each continuation's log-probability after the prefix, from the model's own logits (one pass each).

        The continuation's tokens are those of prefix + continuation after the prefix's own (the
        canonical tail, both NFC-normalised as for llama.cpp); the sum runs over exactly those positions.
        """
        torch = self._torch
        started = time.perf_counter()
        prefix = self._tokenizer(normalised(request.prefix))["input_ids"]
        scores: list[ContinuationScore] = []
        for text in request.continuations:
            whole = self._tokenizer(normalised(request.prefix + text))["input_ids"]
            tail = continuation_tokens(list(prefix), list(whole), text)
            if self.max_positions is not None and len(whole) > self.max_positions:
                raise ModelError(f"scoring {text!r}: {len(whole)} tokens exceed the model's {self.max_positions}")
            ids = torch.tensor([whole])
            with torch.no_grad():
                logits = self._model(input_ids=ids).logits[0]
            logprobs = torch.log_softmax(logits.float(), dim=-1)
            start = len(whole) - len(tail)
            total = sum(float(logprobs[start + k - 1, token]) for k, token in enumerate(tail))
            scores.append(continuation_score(total, len(tail), f"scoring {text!r}: the log-probability"))
        meta = {"engine": "transformers", "mode": "score"}
        return ScoreResult(tuple(scores), time.perf_counter() - started, self.model_name, meta)

    def generate(self, request: ChatRequest) -> ChatResult:
        """Sample or greedily decode up to `max_tokens` new tokens (no grammar: the guard checks)."""
        torch = self._torch
        started = time.perf_counter()
        encoded = self._tokenizer(self.prompt_text(request.messages), return_tensors="pt")
        input_ids = encoded["input_ids"]
        truncated = 0
        if self.max_positions is not None:
            # Keep the newest tokens when the transcript outgrows the model's window.
            room = max(1, self.max_positions - request.max_tokens)
            truncated = max(0, input_ids.shape[1] - room)
            input_ids = input_ids[:, truncated:]
        sampling = request.temperature > 0
        if request.seed is not None:
            torch.manual_seed(request.seed)
        pad_id = self._tokenizer.pad_token_id
        if pad_id is None:
            pad_id = self._tokenizer.eos_token_id
        with torch.no_grad():
            output = self._model.generate(
                input_ids=input_ids,
                attention_mask=torch.ones_like(input_ids),
                max_new_tokens=request.max_tokens,
                do_sample=sampling,
                temperature=request.temperature if sampling else None,
                top_p=None,
                top_k=None,
                pad_token_id=pad_id,
            )
        new_tokens = output[0, input_ids.shape[1] :]
        text = self._tokenizer.decode(new_tokens, skip_special_tokens=True)
        meta: dict[str, Any] = {"engine": "transformers", "constrained": False}
        images = sum(len(m.images) for m in request.messages)
        if images:
            meta["images_dropped"] = images
        if truncated:
            meta["truncated_prompt_tokens"] = truncated
        return ChatResult(
            text=text,
            latency_s=time.perf_counter() - started,
            model=self.model_name,
            prompt_tokens=int(input_ids.shape[1]),
            completion_tokens=int(new_tokens.shape[0]),
            meta=meta,
        )
