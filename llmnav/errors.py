"""llmnav's error hierarchy: one base class, a few narrow subclasses.

The CLI turns any `LlmnavError` into a one-line message and an exit code; anything else is a bug.
"""

from __future__ import annotations


class LlmnavError(Exception):
    """Base of every error llmnav raises on purpose; `str(err)` is a one-line message for the user."""

    exit_code: int = 1


class BadInputError(LlmnavError):
    """The user gave something llmnav cannot use (CLI value, file, path)."""

    exit_code = 2


class ScenarioError(BadInputError):
    """A scenario file is missing, malformed or inconsistent; the message names file, path and problem."""


class BackendSpecError(BadInputError):
    """A backend spec string names no registered backend or has a malformed argument."""


class MissingKeyError(BadInputError):
    """A backend needs an API key; the message names the environment variable to set."""


class ModelUnavailableError(BadInputError):
    """A local model file or engine is absent; nothing is ever downloaded at run time."""


class ImagesRejectedError(BadInputError):
    """The model server takes no images and the run was not allowed to go on without them (the hint says how)."""


class ModelError(LlmnavError):
    """A backend call failed after its last retry (HTTP status, timeout, garbage body)."""


class ReplayDivergenceError(LlmnavError):
    """A strict replay saw a prompt that differs from the recorded one (message has step and diff)."""


class InvalidActionError(LlmnavError):
    """Model output could not be turned into a valid action within the allowed correction turns."""


class VetoedMotionError(LlmnavError):
    """The safety veto blocked every action the model proposed within the allowed negotiation turns."""


class PromptTemplateError(BadInputError):
    """A prompt template is unknown or malformed, or a value it needs was not given (the message names it)."""


def one_line(err: BaseException) -> str:
    """An error's message as one line for logs and the terminal (its class name when it has no message)."""
    text = str(err).strip()
    return text.splitlines()[0] if text else type(err).__name__
