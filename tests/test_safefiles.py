"""The safe file layer: writes never go through a planted link, reads take only regular files in their
folder up to a cap, JSON is parsed with a nesting limit."""

from __future__ import annotations

import json
import os
import threading
from pathlib import Path

import pytest

from llmnav.core import safefiles
from llmnav.core.safefiles import JsonLimitError, UnsafeFileError


def test_write_replaces_a_planted_link_instead_of_writing_through_it(tmp_path: Path) -> None:
    victim = tmp_path / "victim"
    victim.write_text("precious")
    (tmp_path / "out.html").symlink_to(victim)
    safefiles.write_text(tmp_path / "out.html", "page")
    assert victim.read_text() == "precious"
    assert not (tmp_path / "out.html").is_symlink() and (tmp_path / "out.html").read_text() == "page"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.html", "victim"]  # no temporary left behind


def test_read_refuses_a_fifo_without_blocking(tmp_path: Path) -> None:
    fifo = tmp_path / "run.jsonl"
    os.mkfifo(fifo)
    outcome: list[BaseException] = []

    def read() -> None:
        try:
            safefiles.read_bytes(fifo, limit=100, root=tmp_path)
        except BaseException as err:  # noqa: BLE001 - what it raised is the result
            outcome.append(err)

    worker = threading.Thread(target=read, daemon=True)
    worker.start()
    worker.join(10)
    assert not worker.is_alive(), "reading a FIFO blocked"
    assert isinstance(outcome[0], UnsafeFileError) and "not a regular file" in str(outcome[0])


def test_read_refuses_links_out_of_the_folder_and_devices(tmp_path: Path) -> None:
    secret = tmp_path / "secret"
    secret.write_text("id_rsa")
    run = tmp_path / "run"
    run.mkdir()
    (run / "a.jpg").symlink_to(secret)
    (run / "zero").symlink_to("/dev/zero")
    (run / "inside.jpg").write_bytes(b"\xff\xd8\xffok")
    (run / "link.jpg").symlink_to("inside.jpg")
    with pytest.raises(UnsafeFileError, match="leads out of"):
        safefiles.read_bytes(run / "a.jpg", limit=100, root=run)
    with pytest.raises(UnsafeFileError, match="leads out of"):
        safefiles.read_bytes(run / "zero", limit=100, root=run)
    with pytest.raises(UnsafeFileError, match="symbolic link"):
        safefiles.read_bytes(run / "a.jpg", limit=100)  # no folder given: no link at all
    assert safefiles.read_bytes(run / "link.jpg", limit=100, root=run) == b"\xff\xd8\xffok"  # a link inside is fine
    with pytest.raises(FileNotFoundError):
        safefiles.read_bytes(run / "missing", limit=100, root=run)


def test_read_caps_the_size(tmp_path: Path) -> None:
    (tmp_path / "big").write_bytes(b"x" * 101)
    with pytest.raises(UnsafeFileError, match="101 bytes"):
        safefiles.read_bytes(tmp_path / "big", limit=100)
    assert len(safefiles.read_bytes(tmp_path / "big", limit=101)) == 101


def test_image_kind_by_signature() -> None:
    assert safefiles.image_kind(b"\xff\xd8\xff\xe0rest") == "jpeg"
    assert safefiles.image_kind(b"\x89PNG\r\n\x1a\nrest") == "png"
    assert safefiles.image_kind(b"-----BEGIN OPENSSH PRIVATE KEY-----") is None
    assert safefiles.image_kind(b"") is None


def test_loads_refuses_deep_nesting_as_bad_json() -> None:
    with pytest.raises(JsonLimitError, match="nested deeper than 64"):
        safefiles.loads("[" * 200_000)
    with pytest.raises(json.JSONDecodeError):  # callers' handlers of bad JSON take it
        safefiles.loads("[" * 65 + "]" * 65)
    assert safefiles.loads("[" * 64 + "]" * 64) is not None
    assert safefiles.loads(json.dumps({"a": "[" * 100}))["a"] == "[" * 100  # brackets in strings do not nest
    with pytest.raises(JsonLimitError, match="over the limit"):
        safefiles.loads("[1, 2]", max_bytes=3)
    assert "line 1" not in str(JsonLimitError("x"))
