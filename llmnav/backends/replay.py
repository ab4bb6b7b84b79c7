"""Replay backend: `replay:RUN_DIR` or `replay:RUN_DIR/run.jsonl` answers with a recorded run's replies.

It reads the run log's `llm_call` events and returns their replies in order, with the recorded latency
and token counts, so a replayed run reproduces the original's metrics without a model. Strict by default:
each incoming request must equal the recorded one (`ChatRequest.to_log()` after a JSON round trip), else
`ReplayDivergenceError` names the call, step and the first differing message. Loose mode (`?loose` after
the path, as `llmnav drive --replay-loose` writes it, or the `loose=True` option) answers in order anyway.
Recorded failures (`error`) are raised again as `ModelError`.
"""

from __future__ import annotations

import difflib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict

from llmnav.backends.base import (
    Backend,
    BackendStatus,
    ChatRequest,
    ChatResult,
    ContinuationScore,
    ScoreRequest,
    ScoreResult,
)
from llmnav.backends.http import parse_options
from llmnav.backends.reply import continuation_score, duration, seq, token_count
from llmnav.core.safefiles import LOG_LIMIT, UnsafeFileError, read_bytes
from llmnav.core.safefiles import loads as bounded_loads
from llmnav.errors import BackendSpecError, BadInputError, ModelError, ReplayDivergenceError
from llmnav.runs.runlog import RUN_FILE, RunLog, dumps

DIFF_LINES = 8  # lines of unified diff shown after the one-line summary
MODALITIES = ("text", "multimodal")  # the config line's `modality` values


class ReplayOptions(BaseModel):
    """Replay knobs."""

    model_config = ConfigDict(extra="forbid")

    loose: bool = False  # answer in order even when requests differ from the recording


@dataclass(frozen=True)
class RecordedCall:
    """One `llm_call` event of the run log."""

    number: int  # 1-based position among the log's model calls
    line: int  # line in the file (for error messages)
    step: Any
    purpose: str | None
    request: dict[str, Any]
    reply: dict[str, Any] | None
    error: str | None


def split_arg(arg: str) -> tuple[Path, bool]:
    """`PATH[?loose]` → (path of run.jsonl, loose flag)."""
    path, _, query = arg.partition("?")
    loose = False
    for item in filter(None, query.split("&")):
        key, _, value = item.partition("=")
        if key != "loose":
            raise BackendSpecError(f"replay: unknown flag '{key}' in '{arg}' (known: loose)")
        loose = value.lower() not in ("0", "false", "no")
    file = Path(path).expanduser()
    if file.is_dir():
        file = file / RUN_FILE
    return file, loose


@dataclass(frozen=True)
class Recording:
    """A run log as replay needs it: its configuration line and its model calls."""

    file: Path
    config: dict[str, Any]  # empty when the log has no config line (hand-made scripts of old)
    calls: list[RecordedCall]

    def modality(self, *, loose: bool) -> str:
        """`text` or `multimodal`: what the recorded backend was sent, so replay sends the same.

        A log from before the config recorded it cannot be replayed strictly (the planner would not know
        whether to attach camera frames); loose mode assumes multimodal, as replay always did.
        """
        value = self.config.get("modality")
        if value in MODALITIES:
            return str(value)
        if loose:
            return "multimodal"
        if value is None:
            raise BadInputError(
                f"replay: {self.file} was written by an older llmnav: its config line has no 'modality' "
                "(text or multimodal), so what the requests carried is unknown; record it again or add ?loose"
            )
        raise BadInputError(f"replay: {self.file}: config 'modality' is {value!r}, not one of {', '.join(MODALITIES)}")


def load_calls(file: Path) -> list[RecordedCall]:
    """The `llm_call` events of a run log, checked; BadInputError (file and line) on anything malformed."""
    return load_recording(file).calls


def load_recording(file: Path) -> Recording:
    """The config line and `llm_call` events of a run log; BadInputError (file and line) on anything malformed."""
    try:  # a regular file of bounded size: `replay:/dev/zero` or a FIFO is refused, not read without end
        text = read_bytes(file.resolve(), limit=LOG_LIMIT, what=str(file)).decode("utf-8")
    except UnsafeFileError as err:
        raise BadInputError(f"replay: {err}") from None
    except (OSError, UnicodeDecodeError) as err:
        reason = err.strerror if isinstance(err, OSError) and err.strerror else type(err).__name__
        raise BadInputError(f"replay: cannot read {file}: {reason}") from None
    if not text.strip():
        raise BadInputError(f"replay: {file} is empty, not a run log")
    lines = text.split("\n")
    calls: list[RecordedCall] = []
    config: dict[str, Any] = {}
    for number, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        try:
            event = bounded_loads(line)
        except json.JSONDecodeError:
            if number == len(lines) and not text.endswith("\n"):  # torn last line of a killed run
                break
            raise BadInputError(f"replay: {file}: line {number}: not valid JSON") from None
        if not isinstance(event, dict) or "type" not in event:
            raise BadInputError(f"replay: {file}: line {number}: not a run-log event")
        if event["type"] == "llm_call":
            # a heuristic policy's scores may be positive; a model's are log-probabilities
            by_model = not str(config.get("backend") or "").startswith("policy")
            calls.append(_check_call(event, file, number, len(calls) + 1, by_model))
        elif event["type"] == "config" and not config:
            config = event
    return Recording(file, config, calls)


def _check_call(event: dict[str, Any], file: Path, line: int, number: int, by_model: bool = True) -> RecordedCall:
    """One `llm_call` event as a RecordedCall; its reply's counts and scores read as a server's would be."""

    def bad(problem: str) -> BadInputError:
        return BadInputError(f"replay: {file}: line {line}: llm_call {problem}")

    request = event.get("request")
    if not isinstance(request, dict) or not isinstance(request.get("messages"), list):
        raise bad("has no request with messages")
    reply, error = event.get("reply"), event.get("error")
    if reply is None and error is None:
        raise bad("has neither reply nor error")
    if reply is not None:
        if not isinstance(reply, dict) or not isinstance(reply.get("text"), str):
            raise bad("reply has no text")
        try:
            duration(reply.get("latency_s"), "reply latency_s")
            for key in ("prompt_tokens", "completion_tokens"):
                token_count(reply.get(key), f"reply {key}")
            for index, pair in enumerate(seq(reply.get("scores"), "reply scores")):
                if not isinstance(pair, list) or len(pair) != 2:
                    raise ModelError(f"reply score {index + 1} is not a [log-probability, tokens] pair")
                continuation_score(pair[0], pair[1], f"reply score {index + 1}", probability=by_model)
        except ModelError as err:
            raise bad(str(err)) from None
    elif not isinstance(error, str):
        raise bad("error is not a string")
    purpose = event.get("purpose")
    return RecordedCall(
        number,
        line,
        event.get("step"),
        purpose if isinstance(purpose, str) else None,
        request,
        reply,
        error if reply is None else None,
    )


def describe_difference(recorded: dict[str, Any], asked: dict[str, Any]) -> str:
    """First difference between two logged requests: a one-line summary, then a few diff lines."""
    old_msgs, new_msgs = recorded.get("messages", []), asked.get("messages", [])
    for index in range(max(len(old_msgs), len(new_msgs))):
        old = old_msgs[index] if index < len(old_msgs) else None
        new = new_msgs[index] if index < len(new_msgs) else None
        if old == new:
            continue
        if old is None or new is None:
            return (
                f"message {index + 1} is {'extra' if old is None else 'missing'} "
                f"({len(new_msgs)} messages, recorded {len(old_msgs)})"
            )
        role = new.get("role") if isinstance(new, dict) else "?"
        summary = f"message {index + 1} ({role}) differs"
        return summary + "\n" + _diff(_render(old), _render(new))
    for key in sorted(set(recorded) | set(asked)):
        if key != "messages" and recorded.get(key) != asked.get(key):
            return f"{key} differs" + "\n" + _diff(_render(recorded.get(key)), _render(asked.get(key)))
    return "requests differ"


def _render(value: Any) -> list[str]:
    if isinstance(value, dict) and isinstance(value.get("text"), str):  # a message: text line by line
        extra = {k: v for k, v in value.items() if k != "text"}
        return [json.dumps(extra, sort_keys=True), *value["text"].splitlines()]
    return json.dumps(value, indent=1, sort_keys=True).splitlines()


def _diff(old: list[str], new: list[str]) -> str:
    lines = [
        line
        for line in difflib.unified_diff(old, new, "recorded", "now", n=0, lineterm="")
        if not line.startswith(("---", "+++", "@@"))
    ]
    shown = [line if len(line) <= 160 else line[:159] + "…" for line in lines[:DIFF_LINES]]
    if len(lines) > DIFF_LINES:
        shown.append(f"... ({len(lines) - DIFF_LINES} more lines)")
    return "\n".join(shown)


class ReplayBackend(Backend):
    """Answers with the replies recorded in a run log, in order."""

    name = "replay"
    default_arg = None
    description = "Replies recorded in a run log, in order (strict unless ?loose)"
    example = "replay:runs/RUN_ID"
    multimodal = True  # per instance: the recording's modality (see `Recording.modality`)
    deterministic = True

    def __init__(self, arg: str | None = None, **options: Any) -> None:
        super().__init__(arg, **options)
        if not self.arg:
            raise BackendSpecError("replay needs a run: replay:RUN_DIR or replay:RUN_DIR/run.jsonl")
        settings = parse_options(ReplayOptions, self.name, options)
        self.file, spec_loose = split_arg(self.arg)
        self.loose = settings.loose or spec_loose
        recording = load_recording(self.file)
        self.calls = recording.calls
        self.multimodal = recording.modality(loose=self.loose) == "multimodal"
        self.position = 0  # calls answered so far
        self.divergences = 0  # requests that differed (loose mode)
        # A recording that scored continuations replays them; one that only generated cannot score.
        self._scores = any("continuations" in call.request for call in self.calls)

    @property
    def can_score(self) -> bool:
        """Whether the recording holds scoring calls (then a planner deciding `auto` scores again)."""
        return self._scores

    def score(self, request: ScoreRequest) -> ScoreResult:
        """The next recorded scores; strict mode checks the request first."""
        call, diverged = self._next(request.to_log())
        reply = call.reply or {}
        raw = reply.get("scores")
        try:
            scores = tuple(ContinuationScore(float(lp), int(n)) for lp, n in raw)  # type: ignore[union-attr]
        except (TypeError, ValueError):
            raise ModelError(f"replay: call {call.number} at {self.file}:{call.line} holds no scores") from None
        if len(scores) != len(request.continuations):
            raise ModelError(
                f"replay: call {call.number} at {self.file}:{call.line} holds {len(scores)} scores, "
                f"asked for {len(request.continuations)}"
            )
        meta = dict(reply.get("meta") or {})
        if diverged:
            meta["replay_diverged"] = True
        return ScoreResult(scores, float(reply.get("latency_s") or 0.0), str(reply.get("model") or "replay"), meta)

    def _next(self, asked_log: dict[str, Any]) -> tuple[RecordedCall, bool]:
        """The next recorded call, checked against the request in strict mode; raises a recorded failure."""
        if self.position >= len(self.calls):
            raise ModelError(
                f"replay: {self.file} holds {len(self.calls)} model calls and call {self.position + 1} "
                "asked for another (the run went further than the recording)"
            )
        call = self.calls[self.position]
        self.position += 1
        asked = json.loads(dumps(asked_log))  # the same JSON round trip the log went through
        diverged = asked != call.request
        if diverged:
            self.divergences += 1
            if not self.loose:
                where = f"call {call.number} (step {call.step}" + (f", {call.purpose})" if call.purpose else ")")
                raise ReplayDivergenceError(
                    f"replay: {where} differs from the recording at {self.file}:{call.line}: "
                    f"{describe_difference(call.request, asked)}"
                )
        if call.reply is None:
            raise ModelError(f"replay: recorded failure of call {call.number}: {call.error}")
        return call, diverged

    def chat(self, request: ChatRequest) -> ChatResult:
        """The next recorded reply; strict mode checks the request first."""
        call, diverged = self._next(request.to_log())
        reply = call.reply
        assert reply is not None
        meta = dict(reply.get("meta") or {})
        if diverged:
            meta["replay_diverged"] = True
        return ChatResult(
            text=reply["text"],
            latency_s=float(reply.get("latency_s") or 0.0),
            model=str(reply.get("model") or "replay"),
            prompt_tokens=reply.get("prompt_tokens"),
            completion_tokens=reply.get("completion_tokens"),
            meta=meta,
        )

    @property
    def remaining(self) -> int:
        """Recorded calls not yet answered."""
        return len(self.calls) - self.position

    @classmethod
    def status(cls, arg: str | None = None) -> BackendStatus:
        """Always available; it needs a run folder as its argument."""
        if not arg:
            return BackendStatus(True, "needs a recorded run: replay:RUN_DIR")
        try:
            file, _ = split_arg(arg)
            calls = load_calls(file)
        except BadInputError as err:
            return BackendStatus(False, str(err).splitlines()[0])
        return BackendStatus(True, f"{len(calls)} recorded model calls in {file}")


def write_script(
    run_dir: Path, replies: list[str] | list[tuple[str, float]], *, purpose: str = "action", latency_s: float = 0.25
) -> str:
    """Write a hand-made "recording" of model replies and return the spec argument that replays it loosely.

    Each reply is a text, or (text, latency [s]) when the latency matters (the FSM charges it to sim time).
    Loose replay answers in order whatever the prompt, so a script drives any planner: tests use it as a
    scripted model, and a user can try a planner without any model at all.
    """
    with RunLog(run_dir, {"note": "scripted replies", "modality": "multimodal"}) as log:
        for reply in replies:
            text, latency = reply if isinstance(reply, tuple) else (reply, latency_s)
            log.event(
                "llm_call",
                step=0,
                purpose=purpose,
                request={"messages": []},
                reply={"text": text, "latency_s": latency, "model": "script"},
            )
    return f"{Path(run_dir) / RUN_FILE}?loose"
