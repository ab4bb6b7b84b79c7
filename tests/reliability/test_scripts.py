"""Scoring for every script: labels in Chinese, Japanese, Arabic, an emoji or a decomposed accent score with
the local model (llama.cpp in-process), where they once aborted the run as an outage ("model returned tokens
[115], not the forced [15107, 238, 115]": llama.cpp never reports a byte-fallback token that ends inside a
character). A decomposed label scores as its composed form (NFC). Counted as category "scoring scripts".
"""

from __future__ import annotations

import json
import math
import unicodedata
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from llmnav.backends.forced import continuation_tokens, forced_request, score_continuations
from llmnav.backends.local import LocalBackend
from llmnav.cli import app
from llmnav.core.chat import ScoreRequest
from llmnav.errors import ModelError

CATEGORY = "scoring scripts"
SMALL_ROOM = Path(__file__).parents[1] / "runner" / "small_room.yaml"
PREFIX = "Task: find it\nThe robot drives to the"
LABELS = (" 箱子", " 消火器", " صندوق", " 🔥", " cafe\u0301", " café", " box")


@pytest.fixture(scope="module")
def backend() -> LocalBackend:
    made = LocalBackend()
    made.load()
    yield made
    made.close()


def test_labels_in_every_script_score_over_all_their_tokens(backend: LocalBackend, tally: Any) -> None:
    engine: Any = backend.load()
    tally.add(CATEGORY, tried=len(LABELS))
    result = backend.score(ScoreRequest(PREFIX, LABELS))
    by_label = dict(zip(LABELS, result.scores, strict=True))
    for label, score in by_label.items():
        composed = PREFIX + unicodedata.normalize("NFC", label)
        tail = continuation_tokens(engine.tokenize(PREFIX), engine.tokenize(composed), label)
        ok = score.tokens == len(tail) and math.isfinite(score.logprob) and score.logprob < 0
        tally.add(CATEGORY, failures=int(not ok))
        assert ok, (label, score, tail)
    assert by_label[" cafe\u0301"] == by_label[" café"]  # one character, one spelling


def test_a_byte_fallback_score_follows_the_chain_rule(backend: LocalBackend, tally: Any) -> None:
    """log p(" 箱子") = log p(" 箱") + log p("子" | " 箱"): each side built from different requests."""
    tally.add(CATEGORY, tried=1)
    whole = backend.score(ScoreRequest(PREFIX, (" 箱子",))).scores[0]
    first = backend.score(ScoreRequest(PREFIX, (" 箱",))).scores[0]
    second = backend.score(ScoreRequest(PREFIX + " 箱", ("子",))).scores[0]
    ok = first.tokens + second.tokens == whole.tokens and abs(first.logprob + second.logprob - whole.logprob) < 1e-3
    tally.add(CATEGORY, failures=int(not ok))
    assert ok, (whole, first, second)


def test_a_server_that_reports_other_tokens_is_still_a_model_error(tally: Any) -> None:
    """The token-by-token path is for held-back tokens only: ids the grammar did not force stay an error."""
    tally.add(CATEGORY, tried=2)
    tokens = {"p": [1, 2], "p x": [1, 2, 7, 8]}

    def liar(body: dict[str, Any]) -> dict[str, Any]:
        return {"choices": [{"logprobs": {"content": [{"id": 99, "logprob": -1.0}]}}]}

    def silent(body: dict[str, Any]) -> dict[str, Any]:
        return {"choices": [{"logprobs": None}]}

    for complete in (liar, silent):
        with pytest.raises(ModelError, match="returned tokens|no log-probability|no token"):
            score_continuations("p", (" x",), lambda text: tokens.get(text, [3]), complete)
    assert forced_request([1], [2], 5)["logprobs"] == 5


def test_a_scenario_in_chinese_runs_the_default_planner_with_scores(tmp_path: Path, tally: Any) -> None:
    """The default planner (hybrid, `--decide auto`) on the local model, every label and the task in Chinese."""
    tally.add(CATEGORY, tried=1)
    text = SMALL_ROOM.read_text(encoding="utf-8")
    text = text.replace("label: red box, aliases: [box]", "label: 红色箱子, aliases: [箱子]")
    scenario = tmp_path / "small_room_zh.yaml"
    scenario.write_text(text.replace("text: Go to the red box", "text: 去红色箱子"), encoding="utf-8")
    out = tmp_path / "run"
    args = ["drive", "--scenario", str(scenario), "--task-id", "T1", "--backend", "local", "-o", "max_iterations=2",
            "--sensing", "lidar", "--out", str(out), "--quiet"]  # fmt: skip
    result = CliRunner().invoke(app, args)
    summary = json.loads((out / "summary.json").read_text())
    scored = summary["outcome"] != "aborted" and summary["planner_metrics"].get("decide") == "score"
    tally.add(CATEGORY, failures=int(not scored))
    assert scored and result.exit_code in (0, 1), (summary["outcome"], summary["reason"], result.output)
