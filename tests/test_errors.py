"""one_line: the single helper that turns errors and server text into one terminal line."""

from __future__ import annotations

from llmnav.errors import ModelError, one_line


def test_an_error_gives_its_first_line_or_its_class_name() -> None:
    assert one_line(ModelError("HTTP 503 after 3 tries\n  diff line")) == "HTTP 503 after 3 tries"
    assert one_line(ValueError()) == "ValueError"


def test_text_is_flattened_and_shortened() -> None:
    assert one_line("model\n  not\tfound ") == "model not found"
    assert one_line("x" * 50, 10) == "x" * 9 + "…" and len(one_line("y" * 50, 10)) == 10
    assert one_line("short", 10) == "short"
