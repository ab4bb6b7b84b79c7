"""one_line: the single helper that turns errors and server text into one terminal line."""

from __future__ import annotations

import base64
import json

from llmnav.backends.http import url_secrets
from llmnav.errors import ModelError, one_line, redact_secrets


def test_an_error_gives_its_first_line_or_its_class_name() -> None:
    assert one_line(ModelError("HTTP 503 after 3 tries\n  diff line")) == "HTTP 503 after 3 tries"
    assert one_line(ValueError()) == "ValueError"


def test_text_is_flattened_and_shortened() -> None:
    assert one_line("model\n  not\tfound ") == "model not found"
    assert one_line("x" * 50, 10) == "x" * 9 + "…" and len(one_line("y" * 50, 10)) == 10
    assert one_line("short", 10) == "short"


def test_a_secret_is_redacted_in_every_form_it_is_sent_or_echoed() -> None:
    key, password = "sk-A/B+C=d\"e", "p@ss/w+rd"
    url = "http://bob:p%40ss%2Fw%2Brd@example.org/v1"
    basic = base64.b64encode(b"bob:p@ss/w+rd").decode()
    forms = [key, f"Bearer {key}", "sk-A%2FB%2BC%3Dd%22e", json.dumps(key), basic, basic.rstrip("="),
             password, "p%40ss%2Fw%2Brd", base64.urlsafe_b64encode(b"bob:p@ss/w+rd").decode()]  # fmt: skip
    text = " | ".join(forms)
    shown = redact_secrets(text, (key, *url_secrets(url)))
    assert shown.count("***") >= len(forms) and not any(f in shown for f in forms if f != json.dumps(key)), shown
    assert "sk-A" not in shown and "p@ss" not in shown and "bob:" not in shown


def test_a_url_token_without_password_is_a_secret_with_its_basic_form() -> None:
    token = "tok-1234567"
    basic = base64.b64encode(f"{token}:".encode()).decode()
    assert redact_secrets(f"got Basic {basic}", url_secrets(f"http://{token}@host/v1")) == "got Basic ***"
