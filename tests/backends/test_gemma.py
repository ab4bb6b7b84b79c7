"""`local:gemma3-270m`: assembled once from its chunk wheels into the cache, checked, listed with its licence."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest
from typer.testing import CliRunner

from llmnav.backends import gemma
from llmnav.cli import app

pytestmark = pytest.mark.skipif(not gemma.installed(), reason="extra llmnav[gemma] not installed")


def test_assembles_once_into_the_cache_with_the_published_hash(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert gemma.status().ready and "on first use" in gemma.status().detail
    path = gemma.gemma_path()
    assert path == tmp_path / "llmnav" / "models" / "gemma-3-270m-q4_k_m.gguf"
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    assert digest == "a5fd3b62230aa5ec60212297dc9d20eaa70578ac519e00d93a17e44c087a6818"
    assert [p.name for p in path.parent.iterdir()] == [path.name]  # no temporary file left behind
    stamp = path.stat().st_mtime_ns
    assert gemma.gemma_path() == path and path.stat().st_mtime_ns == stamp  # not assembled again


def test_a_truncated_cache_file_is_assembled_again(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    target = tmp_path / "llmnav" / "models" / gemma.FILE_NAME
    target.parent.mkdir(parents=True)
    target.write_bytes(b"GGUF" + b"\0" * 100)  # an interrupted copy of old
    assert gemma.gemma_path().stat().st_size == gemma.SIZE_BYTES


def test_backends_lists_it_with_its_licence(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("COLUMNS", "250")
    result = CliRunner().invoke(app, ["backends"])
    line = next(x for x in result.output.splitlines() if "local:gemma3-270m" in x)
    assert "Gemma terms of use" in line, result.output
