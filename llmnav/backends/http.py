"""The HTTP plumbing shared by the ollama, gemini and openai backends.

One `JsonHttpClient` per backend instance: JSON in, JSON out, with
- connect and read timeouts,
- retries with exponential backoff and jitter on 429, 500/502/503/504 and transport failures
  (refused, reset, timed out, torn replies), honouring a server's `Retry-After` (seconds or HTTP date),
  `retry-after-ms`, and Gemini's `error.details[].retryDelay` ("7s"), up to a cap,
- an optional requests-per-minute limit,
- no retry of a server error whose message names a cause another attempt cannot change (a text-only
  model sent an image, an unsupported feature, a prompt longer than the context),
- one `ModelError` with a one-line message after the last attempt (`HttpStatusError`, with the status
  and the server's reason, when the server answered),
- redaction of API keys from every message it produces (keys travel in headers, never in text).

`HttpBackend.post_chat` is where a backend learns that its server is text-only: the first reply that
rejects an image either stops the run (`ImagesRejectedError`, exit 2, with the hint) or, when the backend
may drop images, resends the request without them and sends none from then on.

`HttpOptions` are the knobs every HTTP backend accepts through `get_backend(spec, **options)`;
`sleep` is injectable so tests run in milliseconds.
"""

from __future__ import annotations

import base64
import email.utils
import ipaddress
import json
import logging
import random
import re
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import TYPE_CHECKING, Any, ClassVar, TypeVar
from urllib.parse import unquote, urlsplit

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from llmnav.backends.base import Backend, ChatRequest, Check, Image, Message
from llmnav.backends.cache import CacheState, ReplyCache
from llmnav.backends.prices import local_server
from llmnav.core.safefiles import loads as bounded_loads
from llmnav.errors import (
    BackendSpecError,
    ImagesRejectedError,
    LlmnavError,
    ModelError,
    one_line,
    redact_secrets,
)

if TYPE_CHECKING:
    import httpx

log = logging.getLogger(__name__)

RETRY_STATUSES = frozenset({429, 500, 502, 503, 504})
REASON_CHARS = 160  # longest server reason quoted in an error message
_SECRET_QUERY = re.compile(r"([?&](?:key|api[_-]?key|access_token|token)=)[^&#\s]+", re.IGNORECASE)
_HTML_HIDDEN = re.compile(r"<(script|style)\b.*?</\1\s*>", re.IGNORECASE | re.DOTALL)
_HTML_TAG = re.compile(r"<[^>]*>")
_DELAY = re.compile(r"^\s*(\d+(?:\.\d+)?)\s*s\s*$")  # protobuf Duration as JSON: "7s", "0.5s"
# A 500 whose message names one of these causes fails the same way every time: retrying only costs time
# (llama.cpp: "image input is not supported", "the request exceeds the available context size").
_PERMANENT_CAUSE = re.compile(
    r"not supported|unsupported|does not support|not implemented|missing data required|"
    r"exceeds the available context|context (?:length|size|window)|too long",
    re.IGNORECASE,
)
# How servers say a model reads no images: llama.cpp without a projector ("image input is not supported
# - hint: ... mmproj"), Ollama ("this model is missing data required for image input", newer releases
# "this model does not support image input"), and the usual wordings of other OpenAI-compatible servers.
_IMAGES_REJECTED = re.compile(
    r"image input|does not support (?:images?|vision|multimodal)|not a multimodal|mmproj|vision is not",
    re.IGNORECASE,
)

# How servers say the model a request names is not theirs: OpenAI and `llmnav serve` ("The model `x`
# does not exist"), vLLM ("The model `x` does not exist."), Ollama ("model 'x' not found").
_MODEL_NOT_FOUND = re.compile(r"model\b.{0,200}\b(?:does not exist|not found)|model_not_found", re.IGNORECASE)

IMAGES_CHECK = "accepts images"  # the probe a run needs only when its sensing includes the image


class HttpOptions(BaseModel):
    """Options every HTTP backend accepts (unknown names are an error, not silently ignored)."""

    model_config = ConfigDict(extra="forbid", arbitrary_types_allowed=True)

    timeout_s: float = Field(default=60.0, gt=0)  # [s] read/write timeout of one attempt
    # [s] one request whole: every attempt, its connect and every wait between them. None: DEADLINE_S, or
    # a `timeout_s` the user set when that is longer (a slow model given more time per answer keeps it)
    deadline_s: float | None = Field(default=None, gt=0)
    connect_timeout_s: float = Field(default=5.0, gt=0)  # [s]
    max_retries: int = Field(default=4, ge=0)  # attempts = max_retries + 1
    backoff_base_s: float = Field(default=1.0, ge=0)  # [s] first backoff ceiling, doubled each retry
    backoff_max_s: float = Field(default=30.0, ge=0)  # [s] ceiling of one backoff
    retry_after_max_s: float = Field(default=120.0, ge=0)  # [s] longest server-requested wait accepted
    rpm: float | None = Field(default=None, gt=0)  # requests per minute; None = unlimited
    base_url: str | None = None  # server base URL override
    drop_images: bool = False  # a server that rejects images: go on without them instead of stopping
    sleep: Callable[[float], None] | None = None  # injectable for tests; default time.sleep


OptionsT = TypeVar("OptionsT", bound=BaseModel)


# `backends --check`: the model list must come whole within CHECK_LIST_TIMEOUT_S (plus as much to connect:
# a dead server is reported within about 10 s); each short chat probe after it gets CHECK_CHAT_TIMEOUT_S.
CHECK_LIST_TIMEOUT_S = 4.0
CHECK_CHAT_TIMEOUT_S = 30.0
MAX_REPLY_BYTES = 64 << 20  # [bytes] one reply (a chat answer with reasoning is at most a few MB)
# [s] a request and all its retries, by default: a dead or dripping server costs a run at most this long
# per request, where five tries of 60 s read + 30 s backoff each once took 930 s
DEADLINE_S = 60.0


def parse_options(model: type[OptionsT], backend: str, options: dict[str, Any]) -> OptionsT:
    """Validate backend options; a bad one becomes a one-line BackendSpecError."""
    try:
        return model(**options)
    except ValidationError as err:
        first = err.errors()[0]
        where = ".".join(str(p) for p in first["loc"]) or "options"
        known = ", ".join(sorted(model.model_fields))
        raise BackendSpecError(f"{backend}: bad option '{where}': {first['msg']} (known: {known})") from None


def redact(text: str, secrets: Iterable[str] = ()) -> str:
    """Remove API keys from text: every known secret in any form, secret query values, URL credentials."""
    return _SECRET_QUERY.sub(r"\1***", redact_secrets(text, secrets))


def url_secrets(url: str) -> tuple[str, ...]:
    """The credentials written into a URL, as secrets to redact wherever they appear.

    `user:password@` gives the password and `user:password` (what Basic auth encodes); a lone `token@` gives
    the token and `token:` (sent as a user with an empty password). Each decoded and as written.
    """
    try:
        parts = urlsplit(url)
    except ValueError:
        return ()
    user, password = parts.username, parts.password
    if password:
        found = [password, f"{user or ''}:{password}"]
    elif user:
        found = [user, f"{user}:"]
    else:
        return ()
    return tuple(unquote(s) for s in found) + tuple(found)


def parse_retry_delay(value: str, now: datetime | None = None) -> float | None:
    """A `Retry-After` value (delta seconds or HTTP date) or a protobuf duration ("7s") as seconds."""
    value = value.strip()
    match = _DELAY.match(value)
    if match:
        return float(match.group(1))
    try:
        return max(0.0, float(value))
    except ValueError:
        pass
    try:
        when = email.utils.parsedate_to_datetime(value)
    except (TypeError, ValueError):
        return None
    if when.tzinfo is None:
        when = when.replace(tzinfo=UTC)
    return max(0.0, (when - (now or datetime.now(UTC))).total_seconds())


def server_retry_delay(response: httpx.Response) -> float | None:
    """How long the server asked us to wait, from headers or a Google RetryInfo detail; None if unsaid."""
    header_ms = response.headers.get("retry-after-ms")
    if header_ms:
        try:
            return max(0.0, float(header_ms) / 1000.0)
        except ValueError:
            pass
    header = response.headers.get("retry-after")
    if header:
        delay = parse_retry_delay(header)
        if delay is not None:
            return delay
    try:
        data = bounded_loads(response.content)
    except ValueError:
        return None
    error = data.get("error") if isinstance(data, dict) else None
    details = error.get("details") if isinstance(error, dict) else None
    if not isinstance(details, list):
        return None
    for detail in details:
        if isinstance(detail, dict) and isinstance(detail.get("retryDelay"), str):
            delay = parse_retry_delay(detail["retryDelay"])
            if delay is not None:
                return delay
    return None


def error_reason(response: httpx.Response) -> str:
    """A short reason for a failed reply: the provider's error message if it gave one."""
    reason = response.reason_phrase or ""
    try:
        data = bounded_loads(response.content)
    except ValueError:
        data = None
    if isinstance(data, dict) and "error" in data:
        err = data["error"]
        if isinstance(err, dict):  # Gemini / OpenAI: {"error": {"message", "status"|"type", "code"}}
            message = err.get("message") or err.get("status") or err.get("type") or ""
            return one_line(f"{reason}: {message}" if message else reason, REASON_CHARS)
        return one_line(f"{reason}: {err}", REASON_CHARS)  # Ollama: {"error": "model not found"}
    text = response.text.strip()
    if "html" in response.headers.get("content-type", "").lower() or text.lower().startswith(("<!doctype", "<html")):
        text = _HTML_TAG.sub(" ", _HTML_HIDDEN.sub(" ", text))  # a proxy's error page: its words, not markup
    return one_line(f"{reason}: {text}" if text.strip() else reason, REASON_CHARS)


def permanent_cause(status: int, reason: str) -> bool:
    """Whether a server error names a cause another attempt cannot change.

    Only 500s: 429 and 502-504 are about load or the way to the server, never about the request.
    """
    return status == 500 and bool(_PERMANENT_CAUSE.search(reason))


def images_rejected(reason: str) -> bool:
    """Whether a server's error message says the model takes no image input."""
    return bool(_IMAGES_REJECTED.search(reason))


class HttpStatusError(ModelError):
    """The server answered with an error status after the last attempt (`status`, the server's `reason`)."""

    def __init__(self, message: str, status: int, reason: str) -> None:
        super().__init__(message)
        self.status = status
        self.reason = reason


def backoff_delay(retry: int, base_s: float, max_s: float, rng: random.Random) -> float:
    """Exponential backoff with jitter: a uniform draw in [½, 1] of min(max, base·2^(retry-1)) [s]."""
    ceiling = min(max_s, base_s * 2.0 ** (retry - 1))
    return ceiling * rng.uniform(0.5, 1.0)


@dataclass
class HttpReply:
    """A successful JSON reply and what it took."""

    data: dict[str, Any]
    status: int
    attempts: int
    elapsed_s: float  # [s] wall time, retries and waits included (a cache hit: the original request's)
    cache: CacheState = "off"  # served from the reply cache ("hit"), stored in it ("miss"), or no cache


class JsonHttpClient:
    """A JSON-over-HTTP client with timeouts, retries, rate limit and key redaction."""

    def __init__(
        self,
        label: str,
        base_url: str,
        options: HttpOptions,
        *,
        headers: dict[str, str] | None = None,
        secrets: Iterable[str] = (),
    ) -> None:
        # deferred: httpx (about 0.1 s) loads only when an HTTP backend builds its client
        import httpx

        self.label = label  # backend name, the prefix of every error message
        self.base_url = base_url.rstrip("/")
        self.options = options
        self._secrets = tuple(s for s in (*secrets, *url_secrets(base_url)) if s)
        self._sleep = options.sleep or time.sleep
        self._rng = random.Random()
        self._last_start = float("-inf")  # [s] monotonic start of the latest reserved request (rate limit)
        self._lock = threading.Lock()
        timeout = httpx.Timeout(options.timeout_s, connect=options.connect_timeout_s)
        self._client = httpx.Client(timeout=timeout, headers=headers or {}, trust_env=False)
        self.cache: ReplyCache | None = None  # POST replies are looked up and stored here when set

    def __repr__(self) -> str:
        return f"<JsonHttpClient {self.label} {self.redact(self.base_url)}>"

    def redact(self, text: str) -> str:
        """Text with this client's secrets removed."""
        return redact(text, self._secrets)

    @property
    def secrets(self) -> tuple[str, ...]:
        """What this client must never show or log: its key, the URL's credentials."""
        return self._secrets

    def post(self, path: str, body: dict[str, Any]) -> HttpReply:
        """POST JSON with retries; raise one ModelError after the last attempt."""
        return self.request("POST", path, body)

    def get(self, path: str, *, timeout_s: float | None = None, retries: bool = True) -> HttpReply:
        """GET JSON (status probes pass a short timeout and no retries)."""
        return self.request("GET", path, None, timeout_s=timeout_s, retries=retries)

    def request(
        self,
        method: str,
        path: str,
        body: dict[str, Any] | None,
        *,
        timeout_s: float | None = None,
        retries: bool = True,
    ) -> HttpReply:
        """Send one request, retrying transient failures; a POST goes through the reply cache when set.

        The ModelError is raised outside any `except` block, so no httpx exception (which may hold
        headers) rides along as its context.
        """
        if self.cache is None or method != "POST" or body is None:
            return self._request(method, path, body, timeout_s=timeout_s, retries=retries)
        key = self.cache.key(self.label, self.base_url, path, body)
        found = self.cache.get(key)
        if found is not None:
            return HttpReply(found.data, 200, 0, found.elapsed_s, "hit")
        reply = self._request(method, path, body, timeout_s=timeout_s, retries=retries)
        self.cache.put(key, reply.data, reply.elapsed_s, self._secrets)
        reply.cache = "miss"
        return reply

    def _request(
        self,
        method: str,
        path: str,
        body: dict[str, Any] | None,
        *,
        timeout_s: float | None,
        retries: bool,
    ) -> HttpReply:
        """`request` without the cache."""
        # deferred: httpx (about 0.1 s), as in the client's constructor
        import httpx

        url = f"{self.base_url}{path}"
        attempts = self.options.max_retries + 1 if retries else 1
        per_attempt = timeout_s or self.options.timeout_s  # [s]
        t0 = time.perf_counter()
        asked = per_attempt if timeout_s or "timeout_s" in self.options.model_fields_set else 0.0  # [s]
        deadline = t0 + (self.options.deadline_s or max(DEADLINE_S, asked))
        failure = "no attempt made"
        status: int | None = None  # the last error status the server answered with, if it answered
        reason = ""
        attempt = 0
        while attempt < attempts:
            attempt += 1
            self._respect_rate_limit()
            server_delay: float | None = None
            budget = min(per_attempt, deadline - time.perf_counter())  # [s] what this attempt may take
            if budget <= 0:
                failure += "; no time left"
                break
            timeout = httpx.Timeout(budget, connect=min(budget, self.options.connect_timeout_s))
            try:
                response = self._send(method, url, body, timeout, deadline)
            except (httpx.InvalidURL, httpx.UnsupportedProtocol) as err:
                failure = f"bad URL: {one_line(str(err), 100)}"
                break
            except httpx.TimeoutException as err:
                failure, status = _timeout_reason(err, round(budget, 1)), None
            except httpx.TransportError as err:
                failure, status = _transport_reason(err), None
            except httpx.HTTPError as err:  # a body that does not decode (a false Content-Encoding): not retried
                failure, status = f"bad reply: {type(err).__name__}: {one_line(str(err), 100)}", None
                break
            else:
                if response.status_code < 400:
                    return HttpReply(self._decode(response), response.status_code, attempt, time.perf_counter() - t0)
                status, reason = response.status_code, error_reason(response)
                failure = f"HTTP {status} {reason}"
                if status not in RETRY_STATUSES or permanent_cause(status, reason):
                    break
                server_delay = server_retry_delay(response)
            if attempt >= attempts:
                break
            if server_delay is not None and server_delay > self.options.retry_after_max_s:
                failure += (
                    f"; server asks to wait {server_delay:.0f} s, over the {self.options.retry_after_max_s:.0f} s limit"
                )
                break
            delay = (
                server_delay
                if server_delay is not None
                else backoff_delay(attempt, self.options.backoff_base_s, self.options.backoff_max_s, self._rng)
            )
            if time.perf_counter() + delay >= deadline:
                failure += f"; no time left to retry within {deadline - t0:.0f} s"
                break
            log.info(
                "%s: %s; retry %d/%d in %.2f s",
                self.label,
                self.redact(failure),
                attempt,
                attempts - 1,
                delay,
            )
            self._sleep(delay)
        elapsed = time.perf_counter() - t0
        noun = "attempt" if attempt == 1 else "attempts"
        message = self.redact(f"{self.label}: {failure} ({attempt} {noun} in {elapsed:.1f} s, {method} {url})")
        if status is not None:
            raise HttpStatusError(message, status, self.redact(reason))
        raise ModelError(message)

    def _send(
        self, method: str, url: str, body: dict[str, Any] | None, timeout: httpx.Timeout, deadline: float
    ) -> httpx.Response:
        """One attempt whose reply must arrive whole within its read plus connect timeouts, and by `deadline`.

        `deadline` is a `time.perf_counter()` value (the request's, shared by its attempts). httpx's read
        timeout bounds each read, not the reply: a server trickling a byte every second would otherwise
        hold an attempt (and the run) for as long as it likes.
        """
        # deferred: httpx (about 0.1 s), as in the client's constructor
        import httpx

        own = time.perf_counter() + (timeout.read or 0.0) + (timeout.connect or 0.0)
        deadline = min(deadline, own)
        with self._client.stream(method, url, json=body, timeout=timeout) as response:
            chunks: list[bytes] = []
            size = 0
            for chunk in response.iter_bytes():
                chunks.append(chunk)
                size += len(chunk)
                if time.perf_counter() > deadline:
                    raise httpx.ReadTimeout("reply not complete in time", request=response.request)
                if size > MAX_REPLY_BYTES:  # a reply is kilobytes; a server sending without end is broken
                    raise httpx.RemoteProtocolError(f"reply over {MAX_REPLY_BYTES >> 20} MB", request=response.request)
            response._content = b"".join(chunks)  # what Response.read() would store
        return response

    def _decode(self, response: httpx.Response) -> dict[str, Any]:
        try:
            data = bounded_loads(response.content)  # a `[` × 200,000 is a bad reply, not a RecursionError
        except (ValueError, UnicodeDecodeError):
            data = None
        if not isinstance(data, dict):
            shown = json.dumps(data) if data is not None else response.content[:60].decode("utf-8", errors="replace")
            snippet = one_line(shown[:60], 60)
            raise ModelError(
                self.redact(
                    f"{self.label}: HTTP {response.status_code} reply is not a JSON object "
                    f"({len(response.content)} bytes: {snippet!r})"
                )
            )
        return data

    def _respect_rate_limit(self) -> None:
        if self.options.rpm is None:
            return
        interval = 60.0 / self.options.rpm  # [s] between request starts
        with self._lock:  # reserve a slot, so threads sharing the backend (FSM assist) stay spaced
            now = time.monotonic()
            start = max(now, self._last_start + interval)
            self._last_start = start
        if start > now:
            self._sleep(start - now)

    def close(self) -> None:
        """Close the connection pool."""
        self._client.close()


def _timeout_reason(err: httpx.TimeoutException, timeout_s: float) -> str:
    # deferred: httpx (about 0.1 s), as in the client's constructor
    import httpx

    if isinstance(err, httpx.ConnectTimeout):
        return f"connect timeout ({timeout_s:g} s)"
    if isinstance(err, httpx.PoolTimeout):
        return "connection pool timeout"
    return f"read timeout ({timeout_s:g} s)"


def _transport_reason(err: httpx.TransportError) -> str:
    text = re.sub(r"\[Errno -?\d+\]\s*", "", str(err)) or type(err).__name__
    return f"connection failed: {one_line(text, 100)}"


def bearer(key: str | None) -> tuple[dict[str, str], tuple[str, ...]]:
    """Headers sending `key` as a Bearer token (none without a key), and the secrets to redact."""
    return ({"Authorization": f"Bearer {key}"}, (key,)) if key else ({}, ())


def normalise_url(url: str) -> str:
    """Add a missing scheme and drop a trailing slash (`OLLAMA_HOST=0.0.0.0:11434` style values).

    A URL no request could use (another scheme, no host, an IPv4 address out of range, a bad port) is a
    BackendSpecError here, before any run folder exists, instead of an aborted run.
    """
    url = url.strip()
    scheme, sep, rest = url.partition("://")
    if sep and not rest.strip("/"):  # `http://` would become http://http: after the slashes went
        raise BackendSpecError(f"server URL {redact(url)}: no host after '{scheme}://'")
    url = url.rstrip("/")
    if "://" not in url:
        url = f"http://{url}"
    check_url(url)
    return url.replace("://0.0.0.0", "://127.0.0.1")


def check_url(url: str) -> None:
    """Refuse a server URL that cannot be requested (the message shows it with secrets redacted)."""
    shown = redact(url)
    try:
        parts = urlsplit(url)
        port = parts.port  # raises ValueError when not a number in 0..65535
    except ValueError as err:
        raise BackendSpecError(f"server URL {shown}: {err}") from None
    if parts.scheme not in ("http", "https"):
        raise BackendSpecError(f"server URL {shown}: scheme '{parts.scheme}' (use http:// or https://)")
    host = parts.hostname or ""
    if not host or not re.fullmatch(r"[A-Za-z0-9._:%-]+", host) or port == 0:
        raise BackendSpecError(f"server URL {shown}: no valid host and port")
    if re.fullmatch(r"[0-9.]+", host):
        try:
            ipaddress.IPv4Address(host)
        except ValueError:
            raise BackendSpecError(f"server URL {shown}: '{host}' is not an IPv4 address") from None


@dataclass
class ChatPost:
    """A chat reply from `HttpBackend.post_chat`, and how many of the request's images were not sent."""

    reply: HttpReply
    images_dropped: int = 0

    def meta(self) -> dict[str, Any]:
        """What the run log records about the call (`images_dropped` only when images were dropped).

        `cache` is lifted out of the reply's meta into the `llm_call` event (`llmnav.planners.observe`).
        """
        meta: dict[str, Any] = {"attempts": self.reply.attempts, "cache": self.reply.cache}
        if self.images_dropped:
            meta["images_dropped"] = self.images_dropped
        return meta


# Servers known to be text-only in this process, by (backend, base URL, model): every episode of a sweep
# learns it from the first rejection, not once each.
_TEXT_ONLY: set[tuple[str, str, str]] = set()
_TEXT_ONLY_LOCK = threading.Lock()


def without_images(request: ChatRequest) -> ChatRequest:
    """The same request with every image removed."""
    messages = tuple(Message(m.role, m.text) for m in request.messages)
    return ChatRequest(messages, request.json_schema, request.temperature, request.max_tokens, request.seed)


def forget_text_only() -> None:
    """Forget which servers turned out text-only (tests)."""
    with _TEXT_ONLY_LOCK:
        _TEXT_ONLY.clear()


class HttpBackend(Backend):
    """What the three HTTP backends share: validated options and one lazily built client."""

    options_model: ClassVar[type[HttpOptions]] = HttpOptions
    example: ClassVar[str] = ""  # a spec string shown by `llmnav backends`
    chat_path: ClassVar[str] = ""  # where `post_chat` sends a request
    models_path: ClassVar[str] = ""  # where the server lists its models (`check`)

    def __init__(self, arg: str | None = None, **options: Any) -> None:
        super().__init__(arg, **options)
        self.settings = parse_options(self.options_model, self.name, options)
        self.drop_images = self.settings.drop_images
        self._client: JsonHttpClient | None = None
        self._client_lock = threading.Lock()  # the FSM assist may call chat from a worker thread
        self.reply_cache: ReplyCache | None = None  # `use_cache`

    def _make_client(self) -> JsonHttpClient:
        """Build this backend's client (base URL, auth headers, secrets to redact)."""
        raise NotImplementedError

    def build_body(self, request: ChatRequest) -> dict[str, Any]:
        """The JSON body of one chat request."""
        raise NotImplementedError

    @property
    def model_name(self) -> str:
        """The model the spec names."""
        return str(self.arg)

    def server_key(self) -> tuple[str, str, str]:
        """(backend, base URL, model): what identifies one server's model for the text-only memory."""
        return (self.name, self.client.base_url, self.model_name)

    def post_chat(self, request: ChatRequest) -> ChatPost:
        """POST a chat request; handle a server that rejects images (see the module docstring)."""
        images = sum(len(m.images) for m in request.messages)
        key = self.server_key()
        if images and key in _TEXT_ONLY and self.drop_images:
            return ChatPost(self.client.post(self.chat_path, self.build_body(without_images(request))), images)
        try:
            return ChatPost(self.client.post(self.chat_path, self.build_body(request)))
        except HttpStatusError as err:
            if err.status == 404 and _MODEL_NOT_FOUND.search(err.reason):  # a name in the spec: bad input
                where = self.client.redact(self.client.base_url)
                raise BackendSpecError(
                    f"{self.name}: the server at {where} does not serve '{self.model_name}' "
                    f"({one_line(err.reason, 160)}); name one it serves in --backend"
                ) from None
            if not images or not images_rejected(err.reason):
                raise
            with _TEXT_ONLY_LOCK:
                first = key not in _TEXT_ONLY
                _TEXT_ONLY.add(key)
            where = f"{self.spec.split('@')[0]} at {self.client.redact(self.client.base_url)}"
            if not self.drop_images:
                cause = one_line(err.reason.split(" - hint")[0], 90)  # llama.cpp appends a hint about projectors
                raise ImagesRejectedError(
                    f"{where} takes no images (HTTP {err.status}: {cause}): "
                    "use --sensing lidar, or --drop-images to go on without images"
                ) from None
            if first:
                log.warning("%s takes no images: going on without them (--drop-images)", where)
        return ChatPost(self.client.post(self.chat_path, self.build_body(without_images(request))), images)

    @property
    def secrets(self) -> tuple[str, ...]:
        """The key and URL credentials this backend holds: a run log redacts them wherever they appear."""
        return self.client.secrets

    @property
    def client(self) -> JsonHttpClient:
        """The backend's HTTP client, built on first use."""
        with self._client_lock:
            if self._client is None:
                self._client = self._make_client()
                self._client.cache = self.reply_cache
            return self._client

    def billing(self) -> dict[str, Any]:
        """The provider (this backend's name), the model, and whether the server is local.

        `local`: on this machine or a private network, where an unlisted model costs 0 (a listed one is
        charged: a proxy on this machine may forward to a paid API).
        """
        return {"provider": self.name, "model": self.model_name, "local": local_server(self.client.base_url)}

    def use_cache(self, cache: ReplyCache) -> bool:
        """Look every POST up in `cache` first and store what the server answers (`--cache DIR`)."""
        self.reply_cache = cache
        with self._client_lock:
            if self._client is not None:
                self._client.cache = cache
        return True

    def listed_models(self, data: dict[str, Any]) -> list[str]:
        """The model names in the server's reply to `models_path`."""
        raise NotImplementedError

    def model_present(self, names: list[str]) -> bool:
        """Whether this backend's model is among `names`."""
        return self.model_name in names

    @classmethod
    def check(cls, arg: str | None = None) -> list[Check]:
        """Probe the spec's server: reachable, models listed, the model present, images, a JSON Schema.

        The last two send one short chat request each (a few tokens), with no retries.
        """
        try:  # short timeouts: a dead or dripping server is reported in seconds, not minutes
            backend = cls(arg, max_retries=0, timeout_s=CHECK_CHAT_TIMEOUT_S, connect_timeout_s=CHECK_LIST_TIMEOUT_S)
        except LlmnavError as err:
            return [Check("configured", False, str(err))]
        try:  # every line, server-provided names included: a server may list a model named after the key
            return [Check(c.name, c.ok, backend.client.redact(c.detail)) for c in backend.check_server()]
        finally:
            backend.close()

    def check_server(self) -> list[Check]:
        """The probes of `check`, on this instance's server."""
        where = self.client.redact(self.client.base_url)
        try:
            reply = self.client.get(self.models_path, retries=False, timeout_s=CHECK_LIST_TIMEOUT_S)
        except ModelError as err:
            return [Check("reachable", False, f"{where}: {short_reason(err)}")]
        names = self.listed_models(reply.data)
        shown = ", ".join(names[:6]) + (", …" if len(names) > 6 else "")
        present = self.model_present(names)
        checks = [
            Check("reachable", True, where),
            Check("models listed", bool(names), f"{len(names)}: {shown}" if names else "none"),
            Check("model present", present, f"{self.model_name} {'is' if present else 'is not'} listed"),
            self._check_images(),
            self._check_schema(),
        ]
        return checks

    def _check_images(self) -> Check:
        request = ChatRequest(
            (Message("user", "What colour is this image? One word.", (_probe_image(),)),), max_tokens=8
        )
        try:
            self.chat(request)
        except ImagesRejectedError:
            return Check(IMAGES_CHECK, False, "text-only server (use --sensing lidar, or --drop-images)")
        except ModelError as err:
            return Check(IMAGES_CHECK, False, f"request failed: {short_reason(err)}")
        return Check(IMAGES_CHECK, True, "answered a request with an image")

    def _check_schema(self) -> Check:
        schema = {
            "type": "object",
            "properties": {"colour": {"type": "string", "enum": ["red", "green", "blue"]}},
            "required": ["colour"],
            "additionalProperties": False,
        }
        request = ChatRequest(
            (Message("user", "Which colour is a clear daytime sky: red, green or blue? Answer in JSON."),),
            json_schema=schema,
            max_tokens=32,
        )
        try:
            text = self.chat(request).text
        except ModelError as err:
            return Check("accepts a JSON Schema", False, f"request failed: {short_reason(err)}")
        try:
            answer = bounded_loads(text)
        except ValueError:
            answer = None
        if isinstance(answer, dict) and set(answer) == {"colour"} and answer["colour"] in ("red", "green", "blue"):
            return Check("accepts a JSON Schema", True, f"answer matches the schema: {one_line(text, 60)}")
        return Check("accepts a JSON Schema", False, f"answer does not match the schema: {one_line(text, 60)!r}")

    def close(self) -> None:
        """Close the HTTP connection pool."""
        with self._client_lock:
            if self._client is not None:
                self._client.close()
                self._client = None


def _probe_image() -> Image:
    """A small plain red JPEG (the image `check` sends)."""
    # deferred: OpenCV and numpy (about 0.2 s) load only for the image check's probe
    import cv2
    import numpy as np

    pixels = np.zeros((32, 32, 3), dtype=np.uint8)
    pixels[:, :, 2] = 255  # OpenCV's channel order is BGR
    ok, buffer = cv2.imencode(".jpg", pixels)
    if not ok:
        raise ModelError("could not encode the probe image")
    return Image(base64.b64encode(buffer.tobytes()).decode("ascii"))


def probe(
    label: str,
    base_url: str,
    path: str,
    *,
    headers: dict[str, str] | None = None,
    secrets: Iterable[str] = (),
    timeout_s: float = 2.0,
) -> HttpReply:
    """One quick GET without retries (for `status()`); raises ModelError with a one-line reason."""
    client = JsonHttpClient(
        label,
        base_url,
        HttpOptions(max_retries=0, timeout_s=timeout_s, connect_timeout_s=timeout_s),
        headers=headers,
        secrets=secrets,
    )
    try:
        return client.get(path, retries=False)
    finally:
        client.close()


def short_reason(err: ModelError) -> str:
    """The reason inside a client error message, without the backend prefix and the attempts trailer."""
    reason = str(err).split(": ", 1)[-1]
    return one_line(reason.rsplit(" (", 1)[0], 100)
