"""Text-only servers: the openai and ollama backends learn from the first image rejection (loopback server).

The rejection texts are the servers' own: llama.cpp's server without a projector answers HTTP 500
"image input is not supported - hint: ...", Ollama "this model is missing data required for image input".
"""

from __future__ import annotations

import base64

import pytest

from llmnav.backends.base import ChatRequest, Image, Message, get_backend
from llmnav.backends.http import forget_text_only
from llmnav.errors import ImagesRejectedError, ModelError

JPEG = Image(base64.b64encode(b"\xff\xd8\xff\xe0text-only-test").decode())
LLAMA_REJECTION = {
    "error": {
        "code": 500,
        "message": "image input is not supported - hint: if this is unexpected, you may need to provide the mmproj",
        "type": "server_error",
    }
}
OLLAMA_REJECTION = {"error": "this model is missing data required for image input"}
OPENAI_OK = {"choices": [{"message": {"role": "assistant", "content": '{"ok": true}'}, "finish_reason": "stop"}]}
OLLAMA_OK = {"model": "m", "message": {"role": "assistant", "content": '{"ok": true}'}, "done": True}


@pytest.fixture(autouse=True)
def _fresh_memory(monkeypatch):
    monkeypatch.delenv("OPENAI_API_KEY", raising=False)
    monkeypatch.delenv("OLLAMA_API_KEY", raising=False)
    forget_text_only()
    yield
    forget_text_only()


def _request(with_image: bool = True) -> ChatRequest:
    images = (JPEG,) if with_image else ()
    return ChatRequest((Message("system", "sys"), Message("user", "where now?", images)))


def _backend(kind: str, url: str, fast: dict, **options):
    if kind == "openai":
        return get_backend(f"openai:m@{url}/v1", **fast, **options)
    return get_backend("ollama:m", base_url=url, **fast, **options)


def _has_image(kind: str, body: dict) -> bool:
    if kind == "openai":
        return any(isinstance(m["content"], list) for m in body["messages"])
    return any("images" in m for m in body["messages"])


CASES = [("openai", LLAMA_REJECTION, OPENAI_OK), ("ollama", OLLAMA_REJECTION, OLLAMA_OK)]


@pytest.mark.parametrize(("kind", "rejection", "ok"), CASES)
def test_first_rejection_stops_with_hint_and_no_retry(server, fast, kind, rejection, ok):
    server.push(server.reply(500, rejection))
    server.default = server.reply(200, ok)
    backend = _backend(kind, server.url, fast)  # fast: max_retries=2 would allow 3 attempts
    with pytest.raises(ImagesRejectedError) as err:
        backend.chat(_request())
    assert len(server.seen) == 1  # a permanent cause is not retried
    message = str(err.value)
    assert "--sensing lidar" in message and "--drop-images" in message
    assert "\n" not in message and "mmproj" not in message


@pytest.mark.parametrize(("kind", "rejection", "ok"), CASES)
def test_drop_images_resends_without_them_and_remembers(server, fast, kind, rejection, ok, caplog):
    server.push(server.reply(500, rejection))
    server.default = server.reply(200, ok)
    backend = _backend(kind, server.url, fast, drop_images=True)
    with caplog.at_level("WARNING"):
        first = backend.chat(_request())
    assert [_has_image(kind, s.body) for s in server.seen] == [True, False]
    assert first.meta["images_dropped"] == 1 and first.text == '{"ok": true}'
    assert sum("takes no images" in r.getMessage() for r in caplog.records) == 1

    # A later episode's backend (same server, same model) sends no image from the start.
    again = _backend(kind, server.url, fast, drop_images=True)
    second = again.chat(_request())
    assert len(server.seen) == 3 and not _has_image(kind, server.seen[2].body)
    assert second.meta["images_dropped"] == 1
    # Text-only requests carry no note.
    assert "images_dropped" not in again.chat(_request(with_image=False)).meta


def test_rejection_of_a_text_request_is_an_ordinary_error(server, fast):
    server.default = server.reply(500, LLAMA_REJECTION)
    with pytest.raises(ModelError) as err:
        _backend("openai", server.url, fast, drop_images=True).chat(_request(with_image=False))
    assert not isinstance(err.value, ImagesRejectedError)
    assert len(server.seen) == 1


def test_transient_500_is_still_retried(server, fast):
    server.default = server.reply(500, {"error": {"message": "An internal error has occurred"}})
    with pytest.raises(ModelError) as err:
        _backend("openai", server.url, fast).chat(_request())
    assert len(server.seen) == fast["max_retries"] + 1
    assert "3 attempts" in str(err.value)


def test_context_overflow_is_not_retried(server, fast):
    server.default = server.reply(
        500, {"error": {"message": "the request exceeds the available context size, try increasing it"}}
    )
    with pytest.raises(ModelError):
        _backend("openai", server.url, fast).chat(_request(with_image=False))
    assert len(server.seen) == 1


def test_ollama_sends_bearer_key_and_redacts_it(server, fast, monkeypatch):
    key = "ollama-proxy-SECRET-123456"
    monkeypatch.setenv("OLLAMA_API_KEY", key)
    server.push(server.reply(200, OLLAMA_OK))
    server.default = server.reply(401, {"error": f"bad key {key}"})
    backend = _backend("ollama", server.url, fast)
    backend.chat(_request(with_image=False))
    assert server.seen[0].headers["authorization"] == f"Bearer {key}"
    with pytest.raises(ModelError) as err:
        backend.chat(_request(with_image=False))
    assert key not in str(err.value) and "***" in str(err.value)
    assert key not in repr(backend) and key not in backend.spec


def test_ollama_without_key_sends_no_authorization(server, fast):
    server.push(server.reply(200, OLLAMA_OK))
    _backend("ollama", server.url, fast).chat(_request(with_image=False))
    assert "authorization" not in server.seen[0].headers
