"""The HTTP front of `llmnav serve`: relays every request to llama.cpp's server and can stop at once.

llama.cpp's server, asked to stop, closes its listening socket and then finishes every response it is
streaming, for as long as generation takes (about 30 s for a long answer), holding the process and the
client's connection. The front owns the sockets clients talk to. `stop` cuts what is in flight: each
upstream connection is shut, so llama.cpp cancels the generation at its next token; a client whose
stream was cut gets a last SSE `error` event and a properly ended response (a request still waiting for
its headers gets HTTP 503), then every client connection is closed.

It also answers `GET /v1/models/{id}` (the OpenAI SDK's `models.retrieve`), which llama.cpp lacks, from
llama.cpp's own model list (with the caller's key, so a missing key is still refused). Every other
path, header and body is relayed unchanged, streamed chunk by chunk.
"""

from __future__ import annotations

import http.client
import json
import re
import socket
import sys
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

# Headers of one connection, never relayed (RFC 9110 §7.6.1), plus those the front sets itself.
_HOP_BY_HOP = frozenset(
    {"connection", "keep-alive", "proxy-connection", "te", "trailer", "transfer-encoding", "upgrade", "host"}
)
_RETRIEVE = re.compile(r"^/(?:v1/)?models/(?P<id>[^/?#]+)/?$")
_CHUNK = 65536
STOPPING = "the server is stopping"


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


class _Server(ThreadingHTTPServer):
    daemon_threads = True
    allow_reuse_address = True
    front: Front

    def __init__(self, address: tuple[str, int], front: Front) -> None:
        self.address_family = socket.AF_INET6 if ":" in address[0] else socket.AF_INET
        self.front = front
        super().__init__(address, _Handler)

    def process_request(self, request: Any, client_address: Any) -> None:
        self.front._track(request)
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

    def __init__(self, host: str, port: int, upstream_port: int) -> None:
        self.upstream_port = upstream_port
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
    def _track(self, client: socket.socket) -> None:
        with self._lock:
            self._clients.add(client)

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

    def do_GET(self) -> None:  # noqa: N802 - the stdlib's naming
        match = _RETRIEVE.match(self.path)
        if match:
            self._retrieve(match["id"])
        else:
            self._relay()

    def _relay(self, path: str | None = None) -> None:
        front = self.server.front
        length = int(self.headers.get("Content-Length") or 0)
        body = self.rfile.read(length) if length > 0 else None
        headers = {k: v for k, v in self.headers.items() if k.lower() not in _HOP_BY_HOP | {"content-length"}}
        exchange = front._open()
        try:
            try:
                exchange.upstream.request(self.command, path or self.path, body=body, headers=headers)
                reply = exchange.upstream.getresponse()
            except (OSError, http.client.HTTPException):
                cut = exchange.cut
                self._error(503 if cut else 502, STOPPING if cut else "llama.cpp's server did not answer")
                return
            self._copy(reply, exchange)
        finally:
            front._close(exchange)

    def _copy(self, reply: http.client.HTTPResponse, exchange: _Exchange) -> None:
        self.send_response(reply.status, reply.reason)
        streamed = reply.getheader("Content-Length") is None and self.command != "HEAD"
        for key, value in reply.getheaders():
            if key.lower() not in _HOP_BY_HOP:
                self.send_header(key, value)
        if streamed:
            self.send_header("Transfer-Encoding", "chunked")
        self.end_headers()
        event_stream = "text/event-stream" in (reply.getheader("Content-Type") or "")
        try:
            while True:
                data = reply.read1(_CHUNK) if streamed else reply.read(_CHUNK)
                if not data:
                    break
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

    def _retrieve(self, model_id: str) -> None:
        """`GET /v1/models/{id}`: the entry of llama.cpp's model list, or OpenAI's 404."""
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
            listed = json.loads(raw).get("data") or []
            found = next((m for m in listed if isinstance(m, dict) and m.get("id") == model_id), None)
            if found is None:
                names = ", ".join(str(m.get("id")) for m in listed if isinstance(m, dict))
                message = f"The model '{model_id}' does not exist (served: {names})"
                body = {"error": {"message": message, "type": "invalid_request_error", "code": "model_not_found"}}
                self._json(404, body)
                return
            self._json(200, {"object": "model", "owned_by": "llmnav", **found})
        finally:
            front._close(exchange)

    def _error(self, status: int, message: str) -> None:
        self.close_connection = True
        self._json(status, {"error": {"message": message, "type": "server_error", "code": status}})

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
