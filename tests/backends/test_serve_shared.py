"""A sweep's shared model server: loopback only, the in-process model's answers, and no orphan process.

Each test starts the bundled SmolLM2 in a `SharedModel` child process (about a second to load).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from llmnav.backends.base import ChatRequest, Message, ScoreRequest
from llmnav.backends.local import DEFAULT_N_CTX, LocalBackend, default_model_path
from llmnav.backends.served import ServedEngine, ServedModel
from llmnav.serve.shared import SharedModel

pytestmark = pytest.mark.skipif(not Path("/proc/self/net/tcp").exists(), reason="reads /proc")

SCHEMA = {
    "type": "object",
    "properties": {
        "reasoning": {"type": "string"},
        "action": {"type": "string", "enum": ["FRONT", "LEFT", "RIGHT", "STOP"]},
        "metres": {"type": "number", "minimum": 0, "maximum": 5},
    },
    "required": ["reasoning", "action", "metres"],
}


def _requests() -> list[ChatRequest]:
    return [
        ChatRequest(
            messages=(Message("system", "You drive a robot in a factory."), Message("user", f"Obstacle {d} m ahead.")),
            temperature=0.0,
            max_tokens=40,
            seed=7,
            json_schema=SCHEMA,
        )
        for d in (0.5, 3.0)
    ]


def _listening(pid: int) -> list[str]:
    """The local addresses (hex, as /proc writes them) of the TCP sockets `pid` listens on."""
    inodes = set()
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        try:
            target = os.readlink(fd)
        except OSError:
            continue
        if target.startswith("socket:["):
            inodes.add(target[8:-1])
    found = []
    for table in ("tcp", "tcp6"):
        for line in Path(f"/proc/{pid}/net/{table}").read_text().splitlines()[1:]:
            fields = line.split()
            if fields[3] == "0A" and fields[9] in inodes:  # state LISTEN
                found.append(fields[1].split(":")[0])
    return found


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def test_listens_on_loopback_only_and_answers_as_the_in_process_model(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("LLMNAV_LOCAL_THREADS", "1")
    in_process = LocalBackend(None)
    expected = [in_process.chat(request).text for request in _requests()]
    score = ScoreRequest(prefix="The robot should turn", continuations=(" left", " right"))
    expected_scores = [s.logprob for s in in_process.score(score).scores]
    with SharedModel(default_model_path(), slots=2, n_ctx=DEFAULT_N_CTX, threads=1) as served:
        assert served.url.startswith("http://127.0.0.1:")
        children = [p for p in Path("/proc").iterdir() if p.name.isdigit() and _is_child_server(p)]
        assert len(children) == 1
        addresses = _listening(int(children[0].name))
        assert len(addresses) >= 2  # the front and llama.cpp's own port behind it
        assert set(addresses) == {"0100007F"}, addresses  # 127.0.0.1 only
        monkeypatch.setenv("LLMNAV_LOCAL_SERVER", served.env()["LLMNAV_LOCAL_SERVER"])
        monkeypatch.setenv("LLMNAV_LOCAL_SERVER_KEY", served.key)
        through_server = LocalBackend(None)
        assert isinstance(through_server.load(), ServedEngine)
        assert [through_server.chat(request).text for request in _requests()] == expected
        assert [s.logprob for s in through_server.score(score).scores] == expected_scores
    assert not _alive(int(children[0].name))  # stopped when the context ended


def _is_child_server(entry: Path) -> bool:
    try:
        cmdline = (entry / "cmdline").read_bytes()
        ppid = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
    except (OSError, ValueError, IndexError):
        return False
    return b"llmnav.serve.shared" in cmdline and ppid == os.getpid()


def test_a_key_is_required_and_another_model_is_not_taken_for_the_served_one(tmp_path: Path) -> None:
    import httpx

    with SharedModel(default_model_path(), slots=1, n_ctx=DEFAULT_N_CTX, threads=1) as served:
        reply = httpx.get(f"{served.url}/v1/models", trust_env=False)
        assert reply.status_code == 401
        assert ServedModel.from_env(served.env()) == served
        assert served.serves(default_model_path(), DEFAULT_N_CTX)
        assert not served.serves(default_model_path(), 4096)
        assert not served.serves(tmp_path / "other.gguf", DEFAULT_N_CTX)
    assert ServedModel.from_env({}) is None


def test_the_server_dies_with_a_killed_sweep(tmp_path: Path) -> None:
    """SIGKILL of the process that started the server (no clean-up runs there) still ends the server."""
    script = (
        "import sys\n"
        "from llmnav.backends.local import DEFAULT_N_CTX, default_model_path\n"
        "from llmnav.serve.shared import SharedModel\n"
        "model = SharedModel(default_model_path(), slots=1, n_ctx=DEFAULT_N_CTX, threads=1)\n"
        "model.start()\n"
        "print(model.process.pid, flush=True)\n"
        "sys.stdin.read()\n"
    )
    sweep = subprocess.Popen(
        [sys.executable, "-c", script], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    try:
        assert sweep.stdout is not None
        server = int(sweep.stdout.readline())
        assert _alive(server)
        sweep.send_signal(signal.SIGKILL)
        sweep.wait(10)
        deadline = time.monotonic() + 10
        while _alive(server) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not _alive(server), "the shared model server outlived the sweep"
    finally:
        sweep.kill()
        sweep.wait()


def test_a_server_that_cannot_start_is_one_error(tmp_path: Path) -> None:
    from llmnav.errors import ModelUnavailableError

    fake = tmp_path / "model.gguf"
    fake.write_bytes(b"GGUF but not a model")
    with pytest.raises(ModelUnavailableError, match="shared model server did not start"):
        SharedModel(fake, slots=2, n_ctx=DEFAULT_N_CTX, threads=1).start()


def test_the_server_runs_this_llmnav_whatever_the_current_folder_holds(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    shadow = tmp_path / "llmnav"
    shadow.mkdir()
    (shadow / "__init__.py").write_text("raise ImportError('the wrong llmnav')\n")
    monkeypatch.chdir(tmp_path)
    with SharedModel(default_model_path(), slots=1, n_ctx=DEFAULT_N_CTX, threads=1) as served:
        assert served.url.startswith("http://127.0.0.1:")
