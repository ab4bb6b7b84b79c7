"""llmnav's error hierarchy: one base class, a few narrow subclasses.

The CLI turns any `LlmnavError` into a one-line message and an exit code; anything else is a bug.
"""

from __future__ import annotations

import base64
import functools
import html
import json
import re
from collections.abc import Iterable
from typing import Any
from urllib.parse import quote, quote_plus


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

    exit_code = 4  # the backend or its server failed, as a run aborted by one exits (never 2: not bad input)


class RunFolderError(LlmnavError):
    """A run folder could not be written (disk full, I/O error); what was written before stays readable."""


class ReplayDivergenceError(LlmnavError):
    """A strict replay saw a prompt that differs from the recorded one (message has step and diff)."""


class InvalidActionError(LlmnavError):
    """Model output could not be turned into a valid action within the allowed correction turns."""


class VetoedMotionError(LlmnavError):
    """The safety veto blocked every action the model proposed within the allowed negotiation turns."""


class SensorFailure(LlmnavError):
    """A range sensor the collision monitor relies on gave no usable data.

    The robot is stopped and the run ends aborted (an outage), never driven on without it.
    """

    exit_code = 4


class FolderLockedError(BadInputError):
    """Another process holds the lock of the ablation or run folder asked for (the message names its pid)."""


class PromptTemplateError(BadInputError):
    """A prompt template is unknown or malformed, or a value it needs was not given (the message names it)."""


# C0 and C1 control characters, DEL, and the Unicode line/paragraph separators: anything a terminal may
# act on (ESC starts title changes and screen clears) or that breaks a line in two.
_CONTROL = re.compile("[\x00-\x1f\x7f-\x9f\u2028\u2029]")


def printable(text: str) -> str:
    """Text safe for a terminal: control characters (ESC, BEL, CR, newline, ...) become visible escapes.

    Everything printed that came from a user file, a model or a server goes through this (or `one_line`).
    """
    return _CONTROL.sub(lambda m: repr(m.group())[1:-1], text)


# `scheme://user:password@host`: credentials written into a URL (httpx sends them as Basic auth)
_USERINFO = re.compile(r"(?<=://)[^/@\s]+@")


def redact_userinfo(text: str) -> str:
    """Text with the credentials of every URL in it replaced by `***` (`http://***@host/v1`)."""
    return _USERINFO.sub("***@", text)


MIN_SECRET_CHARS = 4  # shorter "secrets" are not redacted: one letter would blank out the text


def secret_forms(secret: str) -> set[str]:
    """Every form in which llmnav sends `secret`, or a server or a writer may show it again.

    As written; URL-encoded (path, query and form styles, as a URL or a query string carries it); base64 in
    the standard and URL-safe alphabets, padded or not (HTTP Basic auth sends `user:password` so);
    JSON-escaped (a run-log line) and HTML-escaped (a page).
    """
    raw = secret.encode("utf-8", errors="surrogatepass")
    encoded = [base64.b64encode(raw).decode(), base64.urlsafe_b64encode(raw).decode()]
    forms = {secret, quote(secret, safe=""), quote(secret), quote_plus(secret), html.escape(secret)}
    forms |= {*encoded, *(e.rstrip("=") for e in encoded)}
    forms |= {json.dumps(secret)[1:-1], json.dumps(secret, ensure_ascii=False)[1:-1]}
    return forms


@functools.lru_cache(maxsize=64)
def _expanded(secrets: frozenset[str]) -> tuple[str, ...]:
    forms = {form for secret in secrets for form in secret_forms(secret)}
    return tuple(sorted((f for f in forms if len(f) >= MIN_SECRET_CHARS), key=len, reverse=True))


def expand_secrets(secrets: Iterable[str]) -> tuple[str, ...]:
    """The secrets (of at least MIN_SECRET_CHARS) in all their `secret_forms`, longest first.

    Longest first, so a secret containing another is not left half shown.
    """
    return _expanded(frozenset(s for s in secrets if len(s) >= MIN_SECRET_CHARS))


def redact_secrets(text: str, secrets: Iterable[str]) -> str:
    """Text with each secret (a key, URL credentials) in any of its `secret_forms`, and URL userinfo, as `***`."""
    for form in expand_secrets(secrets):
        text = text.replace(form, "***")
    return redact_userinfo(text)


def one_line(value: BaseException | str, limit: int | None = None) -> str:
    """One printable line for logs and the terminal, at most `limit` characters (shortened with "…").

    An error gives its message's first line (its class name when it has no message); a text (a server's
    reply, an engine's complaint) is flattened, every run of whitespace becoming one space. Control
    characters are escaped either way.
    """
    if isinstance(value, BaseException):
        text = str(value).strip()
        line = text.splitlines()[0].strip() if text else type(value).__name__
    else:
        line = " ".join(str(value).split())
    line = printable(line)
    return line if limit is None or len(line) <= limit else line[: limit - 1] + "…"


def validation_message(err: Any) -> str:
    """The first problem of a pydantic ValidationError as one line: `field.path: message`."""
    first = err.errors()[0]
    where = ".".join(str(p) for p in first["loc"]) or "(top level)"
    return one_line(f"{where}: {first['msg'].removeprefix('Value error, ')}")
