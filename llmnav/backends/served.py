"""The local backend's model held by another process: the one copy a sweep's workers share.

An ablation with the local model and several workers can load the model once, in one server process
with a slot per worker (`llmnav.serve.shared`), instead of once in every worker. Each worker's `local`
backend then sends that server the very requests the in-process engine hands llama.cpp (the same
bodies, grammars and seeds, answered by the same server code) over HTTP on 127.0.0.1, with the server's
key. The backend spec stays `local`, so run logs, episode conditions and the manifest do not depend on
the layout.

The sweep names the server in its workers' environment only ($LLMNAV_LOCAL_SERVER: `URL N_CTX PATH`;
its key in $LLMNAV_LOCAL_SERVER_KEY). A `local` backend whose model file or context differs from the
served one loads its own copy as usual.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from llmnav.backends.llamacpp import LlamaCppEngine
from llmnav.errors import ModelError, one_line

SERVER_ENV = "LLMNAV_LOCAL_SERVER"
KEY_ENV = "LLMNAV_LOCAL_SERVER_KEY"
REQUEST_TIMEOUT_S = 600.0  # [s] one answer; a 135M model looping to max_tokens on a busy box took 72 s


@dataclass(frozen=True)
class ServedModel:
    """Where a shared model is served, and which model with which context per slot."""

    url: str  # http://127.0.0.1:PORT (no /v1)
    n_ctx: int  # [tokens] per slot
    model_path: Path
    key: str

    def env(self) -> dict[str, str]:
        """The variables that point a worker's `local` backend at this server."""
        return {SERVER_ENV: f"{self.url} {self.n_ctx} {self.model_path}", KEY_ENV: self.key}

    @classmethod
    def from_env(cls, environ: dict[str, str]) -> ServedModel | None:
        """The server named in `environ`, or None when there is none (or the variables are malformed)."""
        parts = environ.get(SERVER_ENV, "").split(" ", 2)
        if len(parts) != 3 or not parts[1].isdigit():
            return None
        return cls(parts[0], int(parts[1]), Path(parts[2]), environ.get(KEY_ENV, ""))

    def serves(self, path: Path, n_ctx: int) -> bool:
        """Whether this server holds model `path` with `n_ctx` tokens per slot."""
        return self.n_ctx == n_ctx and self.model_path.resolve() == path.resolve()


class ServedEngine(LlamaCppEngine):
    """`LlamaCppEngine` whose requests go over HTTP to the shared server instead of an in-process one."""

    def __init__(self, served: ServedModel) -> None:  # loads nothing: the server holds the model
        # deferred: httpx (about 0.1 s) loads only when a served model is used
        import httpx

        self._served = served
        self._key = served.key
        self._client = httpx.Client(
            base_url=served.url,
            headers={"Authorization": f"Bearer {served.key}"},
            timeout=httpx.Timeout(REQUEST_TIMEOUT_S, connect=5.0),
            trust_env=False,  # loopback: never through a proxy
        )
        self._tokens: dict[str, list[int]] = {}
        self.model_name = served.model_path.name.removesuffix(".gguf")
        self.n_ctx = served.n_ctx
        self.threads = 0  # the server's
        self._checked_schemas: set[str] = set()

    def _post(self, path: str, body: dict[str, Any]) -> dict[str, Any]:
        """The server's JSON reply; an error reply as `{"error": ...}`, like the in-process handlers give."""
        # deferred: httpx (about 0.1 s), as in the client's constructor
        import httpx

        try:
            response = self._client.post(path, json=body)
            reply = response.json()
        except (httpx.HTTPError, ValueError) as err:
            raise ModelError(f"the sweep's shared model server did not answer: {one_line(err)}") from None
        if not isinstance(reply, dict):
            raise ModelError("the sweep's shared model server answered something other than a JSON object")
        if response.status_code != 200 and "error" not in reply:
            reply = {"error": {"message": f"HTTP {response.status_code}"}}
        return reply

    def _chat_completions(self, body: dict[str, Any]) -> dict[str, Any]:
        return self._post("/v1/chat/completions", body)

    def _completions(self, body: dict[str, Any]) -> dict[str, Any]:
        return self._post("/v1/completions", body)

    def _tokenizer(self) -> Any:
        return self._client  # base URL the server's root, where llama.cpp keeps /tokenize
