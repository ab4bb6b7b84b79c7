"""The HTTP front of `llmnav serve`: relays every request to llama.cpp's server and can stop at once.

llama.cpp's server, asked to stop, closes its listening socket and then finishes every response it is
streaming, for as long as generation takes (about 30 s for a long answer), holding the process and the
client's connection. The front owns the sockets clients talk to. `stop` cuts what is in flight: each
upstream connection is shut, so llama.cpp cancels the generation at its next token; a client whose
stream was cut gets a last SSE `error` event and a properly ended response (a request still waiting for
its headers gets HTTP 503), then every client connection is closed.

Every request is bounded before it reaches llama.cpp (the limits are `Limits`, stated there):
- a request whose headers do not arrive whole within `header_s`, a body that does not within `body_s`,
  and a keep-alive connection idle for `idle_s` are closed;
- with a key, a request carrying a body is refused (401) on its headers, before a byte of the body is read;
- a Content-Length that is not one decimal number gets 400, one over `max_body_bytes` 413, a chunked (or
  otherwise transfer-encoded) body 411: llama.cpp's clients always send a length;
- connections beyond `max_connections` are closed at once (each holds a thread).

It also answers `GET /v1/models/{id}` (the OpenAI SDK's `models.retrieve`), which llama.cpp lacks, from
llama.cpp's own model list (with the caller's key, so a missing key is still refused), and lists each
alias as a model. What it changes so that OpenAI's SDKs get OpenAI's answers (unknown model names, legacy
completion log-probabilities, the Responses API's `text.format`, error texts) is in `llmnav.serve.compat`.
Every other path, header and body is relayed unchanged, streamed chunk by chunk.
"""

from __future__ import annotations

import hmac
import http.client
import json
import re
import socket
import sys
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any
from urllib.parse import unquote

from llmnav.serve.compat import Adapted, Refusal, adapt_request, error_body, true_error, unknown_model

# Headers of one connection, never relayed (RFC 9110 §7.6.1), plus those the front sets itself.
_HOP_BY_HOP = frozenset(
    {"connection", "keep-alive", "proxy-connection", "te", "trailer", "transfer-encoding", "upgrade", "host"}
)
_RETRIEVE = re.compile(r"^/(?:v1/)?models/(?P<id>[^?#]+?)/?(?:[?#].*)?$")  # ids may hold "/" (org/name)
_LIST = re.compile(r"^/(?:v1/)?models/?(?:[?#].*)?$")
_CHUNK = 65536
_LENGTH = re.compile(r"[0-9]{1,18}")  # one decimal Content-Length (18 digits: no overflow, far over any cap)
STOPPING = "the server is stopping"


@dataclass(frozen=True)
class Limits:
    """What one client may take of the server."""

    max_body_bytes: int = 32 << 20  # [bytes] a chat request with a few camera frames is a few MB
    header_s: float = 10.0  # [s] from a request's first byte to the end of its headers
    body_s: float = 60.0  # [s] to send the whole body, however it trickles
    idle_s: float = 60.0  # [s] a keep-alive connection may wait for its next request
    max_connections: int = 256  # open client connections (each holds a thread)


class _Watchdog:
    """Closes a connection whose current phase (headers, body) outlives its deadline.

    A socket timeout bounds each read, not a phase: a client sending a byte a second would never trip it.
    """

    def __init__(self, connection: socket.socket) -> None:
        self._connection = connection
        self._timer: threading.Timer | None = None

    def arm(self, seconds: float) -> None:
        self.disarm()
        self._timer = threading.Timer(seconds, self._expire)
        self._timer.daemon = True
        self._timer.start()

    def disarm(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None

    def _expire(self) -> None:
        try:
            self._connection.shutdown(socket.SHUT_RDWR)  # the handler's read returns at once: it ends
        except OSError:
            pass


class _Exchange:
    """One request being relayed: its upstream connection, cut by `Front.stop`."""

    def __init__(self, upstream: http.client.HTTPConnection) -> None:
        self.upstream = upstream
        self.cut = False

    def sever(self) -> None:
        self.cut = True
        sock = self.upstream.sock
        if sock is not None:
            try:
                sock.shutdown(socket.SHUT_RDWR)  # wakes the relaying thread's read; llama.cpp sees the close
            except OSError:
                pass


class _Events:
    """A server-sent event stream whose `data:` JSON objects are changed by an adapter as they pass."""

    def __init__(self, adapted: Adapted) -> None:
        self._adapted = adapted
        self._pending = b""
        self.open = True  # False once the upstream ended and the rest was given back

    def feed(self, data: bytes) -> bytes:
        """The complete events in what arrived so far, changed; an unfinished one waits for more."""
        self._pending += data
        head, separator, self._pending = self._pending.rpartition(b"\n\n")
        return b"".join(self._event(e) + b"\n\n" for e in head.split(b"\n\n")) if separator else b""

    def rest(self) -> bytes:
        """What is left when the upstream ends (an event cut short is passed on as it came)."""
        rest, self._pending, self.open = self._pending, b"", False
        return rest

    def _event(self, event: bytes) -> bytes:
        lines = []
        for line in event.split(b"\n"):
            if line.startswith(b"data: ") and line[6:].strip() != b"[DONE]":
                try:
                    data = json.loads(line[6:])
                except ValueError:
                    data = None
                if isinstance(data, dict) and "error" not in data:
                    line = b"data: " + json.dumps(self._adapted.reply(data)).encode()
            lines.append(line)
        return b"\n".join(lines)


class _Server(ThreadingHTTPServer):
    daemon_threads = True
    allow_reuse_address = True
    front: Front

    def __init__(self, address: tuple[str, int], front: Front) -> None:
        self.address_family = socket.AF_INET6 if ":" in address[0] else socket.AF_INET
        self.front = front
        super().__init__(address, _Handler)

    def process_request(self, request: Any, client_address: Any) -> None:
        if not self.front._track(request):  # over the connection cap: no thread for it
            self.shutdown_request(request)
            return
        super().process_request(request, client_address)

    def handle_error(self, request: Any, client_address: Any) -> None:
        # A client that hangs up (Ctrl-C in `llm chat`), or any connection cut while stopping, is expected.
        if not (self.front.stopping.is_set() or isinstance(sys.exc_info()[1], ConnectionError)):
            super().handle_error(request, client_address)

    def shutdown_request(self, request: Any) -> None:
        self.front._untrack(request)
        super().shutdown_request(request)


class Front:
    """Listen on `host:port` and relay to llama.cpp on 127.0.0.1:`upstream_port`."""

    def __init__(
        self,
        host: str,
        port: int,
        upstream_port: int,
        api_key: str | None = None,
        limits: Limits | None = None,
        names: Sequence[str] = (),
    ) -> None:
        self.upstream_port = upstream_port
        self.api_key = api_key
        self.names = tuple(names)  # the served model name, then its aliases; empty: any name is relayed
        self.limits = limits or Limits()
        self._lock = threading.Lock()
        self._exchanges: set[_Exchange] = set()
        self._clients: set[socket.socket] = set()
        self.stopping = threading.Event()
        self._server = _Server((host, port), self)  # OSError when the address cannot be bound
        self._thread = threading.Thread(target=self._server.serve_forever, name="llmnav-serve-front", daemon=True)

    @property
    def port(self) -> int:
        """The port it listens on (the one the OS chose when asked for 0)."""
        return int(self._server.server_address[1])

    def start(self) -> None:
        """Accept connections (in a background thread)."""
        self._thread.start()

    def stop(self, drain_s: float = 0.5) -> None:
        """Stop accepting, cut every relayed request, then close every client connection."""
        self.stopping.set()
        if self._thread.is_alive():
            self._server.shutdown()
        self._server.server_close()
        with self._lock:
            exchanges = list(self._exchanges)
        for exchange in exchanges:
            exchange.sever()
        # The relaying threads end their responses (an error event, or 503) as soon as their read wakes.
        deadline = threading.Event()
        for _ in range(int(drain_s / 0.02)):
            with self._lock:
                if not self._exchanges:
                    break
            deadline.wait(0.02)
        with self._lock:
            clients = list(self._clients)
        for client in clients:  # idle keep-alive connections, and any response still not ended
            try:
                client.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass

    # --- bookkeeping (called by the server and the handlers) ----------------------------------------
    def _track(self, client: socket.socket) -> bool:
        """Count a new client connection; False when the cap is reached (it is then closed)."""
        with self._lock:
            if len(self._clients) >= self.limits.max_connections:
                return False
            self._clients.add(client)
            return True

    def _untrack(self, client: socket.socket) -> None:
        with self._lock:
            self._clients.discard(client)

    def _open(self) -> _Exchange:
        exchange = _Exchange(http.client.HTTPConnection("127.0.0.1", self.upstream_port))
        with self._lock:
            self._exchanges.add(exchange)
        if self.stopping.is_set():
            exchange.sever()
        return exchange

    def _close(self, exchange: _Exchange) -> None:
        with self._lock:
            self._exchanges.discard(exchange)
        exchange.upstream.close()


class _Handler(BaseHTTPRequestHandler):
    protocol_version = "HTTP/1.1"
    server: _Server

    def log_message(self, format: str, *args: Any) -> None:  # noqa: A002 - the stdlib's signature
        return  # llama.cpp logs requests itself with --verbose

    def setup(self) -> None:
        super().setup()
        self.watchdog = _Watchdog(self.connection)

    def finish(self) -> None:
        self.watchdog.disarm()
        super().finish()

    def handle_one_request(self) -> None:
        """Wait up to `idle_s` for a request, then give its headers `header_s` (the handler disarms it)."""
        limits = self.server.front.limits
        self.connection.settimeout(limits.idle_s)
        try:
            if not self.rfile.peek(1):  # type: ignore[attr-defined]  # a BufferedReader (rbufsize -1): empty at EOF
                self.close_connection = True
                return
        except OSError:  # idle too long (TimeoutError), or reset
            self.close_connection = True
            return
        self.connection.settimeout(limits.header_s)
        self.watchdog.arm(limits.header_s)
        try:
            super().handle_one_request()
        except OSError:  # the watchdog cut a phase that ran over, or the client vanished
            self.close_connection = True
        finally:
            self.watchdog.disarm()

    def _body(self) -> bytes | None:
        """The request's body, read only once its headers pass (key, length); None after an error reply."""
        self.watchdog.disarm()  # the headers are in
        front = self.server.front
        limits = front.limits
        encoding = self.headers.get("Transfer-Encoding")
        lengths = self.headers.get_all("Content-Length") or []
        if front.api_key is not None and (encoding or any(v.strip() not in ("", "0") for v in lengths)):
            if not self._authorised(front.api_key):
                self._error(401, "Invalid API Key", "authentication_error")
                return None
        if encoding:
            self._error(411, "send the body with a Content-Length (no Transfer-Encoding)", "invalid_request_error")
            return None
        if len({v.strip() for v in lengths}) > 1 or not all(_LENGTH.fullmatch(v.strip()) for v in lengths):
            self._error(400, "Content-Length is not one decimal number", "invalid_request_error")
            return None
        length = int(lengths[0]) if lengths else 0
        if length > limits.max_body_bytes:
            self._error(413, f"request body over {limits.max_body_bytes} bytes", "invalid_request_error")
            return None
        if not length:
            return b""
        self.watchdog.arm(limits.body_s)
        try:
            body = self.rfile.read(length)
        except OSError:
            body = b""
        self.watchdog.disarm()
        if len(body) < length:  # cut by the watchdog or the client: nothing to answer on
            self.close_connection = True
            return None
        return body

    def _authorised(self, key: str) -> bool:
        """Whether the request carries `key` as a Bearer token (or as llama.cpp's `X-Api-Key`)."""
        sent = self.headers.get("Authorization", "")
        token = sent[7:].strip() if sent[:7].lower() == "bearer " else self.headers.get("X-Api-Key", "")
        return hmac.compare_digest(token.encode("utf-8", "surrogateescape"), key.encode())

    def do_GET(self) -> None:  # noqa: N802 - the stdlib's naming
        match = _RETRIEVE.match(self.path)
        listing = _LIST.match(self.path)
        if match or listing:
            if self._body() is not None:  # checked and dropped: the list is asked for without one
                self._models(unquote(match["id"]) if match else None)
        else:
            self._relay()

    def _relay(self, path: str | None = None) -> None:
        front = self.server.front
        body = self._body()
        if body is None:
            return
        adapted = adapt_request(self.command, self.path, body, front.names)
        if isinstance(adapted, Refusal):
            self._json(adapted.status, adapted.body)
            return
        headers = {k: v for k, v in self.headers.items() if k.lower() not in _HOP_BY_HOP | {"content-length"}}
        exchange = front._open()
        try:
            try:
                exchange.upstream.request(self.command, path or self.path, body=adapted.body or None, headers=headers)
                reply = exchange.upstream.getresponse()
            except (OSError, http.client.HTTPException):
                cut = exchange.cut
                self._error(503 if cut else 502, STOPPING if cut else "llama.cpp's server did not answer")
                return
            self._copy(reply, exchange, adapted)
        finally:
            front._close(exchange)

    def _copy(self, reply: http.client.HTTPResponse, exchange: _Exchange, adapted: Adapted) -> None:
        streamed = reply.getheader("Content-Length") is None and self.command != "HEAD"
        json_reply = "application/json" in (reply.getheader("Content-Type") or "")
        rewrite = reply.status >= 400 or adapted.changes_replies
        if not streamed and json_reply and rewrite and self.command != "HEAD":
            self._rewrite(reply, exchange, adapted)  # a whole JSON reply, small: read, change, send
            return
        self.send_response(reply.status, reply.reason)
        for key, value in reply.getheaders():
            if key.lower() not in _HOP_BY_HOP:
                self.send_header(key, value)
        if streamed:
            self.send_header("Transfer-Encoding", "chunked")
        self.end_headers()
        event_stream = "text/event-stream" in (reply.getheader("Content-Type") or "")
        events = _Events(adapted) if streamed and event_stream and adapted.changes_replies else None
        try:
            while True:
                data = reply.read1(_CHUNK) if streamed else reply.read(_CHUNK)
                if events is not None:
                    data = events.feed(data) if data else events.rest()
                    if not data and not events.open:
                        break
                elif not data:
                    break
                if data:
                    self.wfile.write(b"%x\r\n%s\r\n" % (len(data), data) if streamed else data)
                    self.wfile.flush()
        except (OSError, http.client.HTTPException):  # a cut upstream ends mid-chunk
            if not exchange.cut:
                raise
        if exchange.cut:
            self.close_connection = True
            if streamed and event_stream:  # end the event stream the way a server-side error does
                event = b'\n\ndata: {"error": {"message": "%s", "type": "server_stopping"}}\n\n' % STOPPING.encode()
                self.wfile.write(b"%x\r\n%s\r\n" % (len(event), event))
        if streamed:
            self.wfile.write(b"0\r\n\r\n")
        self.wfile.flush()

    def _rewrite(self, reply: http.client.HTTPResponse, exchange: _Exchange, adapted: Adapted) -> None:
        """Send a whole JSON reply changed as OpenAI would answer (an error's true text, legacy logprobs)."""
        try:
            raw = reply.read()
        except (OSError, http.client.HTTPException):
            self._error(503 if exchange.cut else 502, STOPPING if exchange.cut else "llama.cpp's reply was cut")
            return
        try:
            data = json.loads(raw)
        except ValueError:
            data = None
        if isinstance(data, dict):
            data = true_error(data) if reply.status >= 400 else adapted.reply(data)
            raw = json.dumps(data).encode()
        self.send_response(reply.status, reply.reason)
        for key, value in reply.getheaders():
            if key.lower() not in _HOP_BY_HOP | {"content-length"}:
                self.send_header(key, value)
        self.send_header("Content-Length", str(len(raw)))
        self.end_headers()
        self.wfile.write(raw)
        self.wfile.flush()

    def _models(self, model_id: str | None) -> None:
        """`GET /v1/models` with an entry per alias, or `GET /v1/models/{id}`: one entry, or OpenAI's 404."""
        front = self.server.front
        headers = {k: v for k, v in self.headers.items() if k.lower() in ("authorization", "x-api-key")}
        exchange = front._open()
        try:
            try:
                exchange.upstream.request("GET", "/v1/models", headers=headers)
                reply = exchange.upstream.getresponse()
                raw = reply.read()
            except (OSError, http.client.HTTPException):
                self._error(503, STOPPING if exchange.cut else "llama.cpp's server did not answer")
                return
            if reply.status != 200:
                self._json(reply.status, json.loads(raw or b"{}"))
                return
            reply_body = json.loads(raw)
            listed = [m for m in reply_body.get("data") or [] if isinstance(m, dict)]
            if front.names and listed:  # llama.cpp lists the served name; each alias is an entry of its own
                served = listed[0]
                aliases = [{**served, "id": name} for name in front.names if name != served.get("id")]
                listed = [served, *aliases, *listed[1:]]
            if model_id is None:
                self._json(200, {**reply_body, "data": listed})
                return
            found = next((m for m in listed if m.get("id") == model_id), None)
            if found is None:
                names = front.names or tuple(str(m.get("id")) for m in listed)
                self._json(404, unknown_model(model_id, names).body)
                return
            self._json(200, {"object": "model", "owned_by": "llmnav", **found})
        finally:
            front._close(exchange)

    def _error(self, status: int, message: str, kind: str = "server_error") -> None:
        self.close_connection = True
        self._json(status, error_body(message, kind, status))

    def _json(self, status: int, body: dict[str, Any]) -> None:
        data = json.dumps(body).encode()
        self.send_response(status)
        self.send_header("Content-Type", "application/json; charset=utf-8")
        self.send_header("Content-Length", str(len(data)))
        if self.close_connection:
            self.send_header("Connection", "close")
        self.end_headers()
        self.wfile.write(data)
        self.wfile.flush()


for _method in ("POST", "PUT", "DELETE", "OPTIONS", "HEAD", "PATCH"):
    setattr(_Handler, f"do_{_method}", _Handler._relay)
