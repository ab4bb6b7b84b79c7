"""Prompt templates: load, render and fingerprint the Markdown files in `prompts/`.

A template is `prompts/NAME.md`, plain Markdown with `$name` placeholders (`string.Template`; write `$$`
for a literal dollar sign) and three kinds of HTML-comment directives, invisible to Markdown readers:

- `<!-- include PART -->` — replaced by `prompts/parts/PART.md` (so the stepwise variants share their
  sections instead of repeating them);
- `<!-- if FLAG -->` ... `<!-- endif -->` (or `<!-- if not FLAG -->`) — kept only when the value FLAG
  is truthy (e.g. the image guidelines only when images are sent); not nested;
- any other `<!-- ... -->` — a note for maintainers, removed from the rendered text.

`template_hash` fingerprints a template with its includes expanded, so the run config changes whenever
any text the model could see changes.

Every function takes an optional `package`: the importable package whose `prompts/` folder holds the
templates, read through `importlib.resources` (so a plug-in planner ships its own, in a wheel or a zip
alike, and names it in `Planner.prompt_package`). Without it, llmnav's bundled `prompts/` folder is read.
"""

from __future__ import annotations

import hashlib
import re
from importlib import resources
from importlib.resources.abc import Traversable
from pathlib import Path
from string import Template
from typing import Any

from llmnav.core.resources import resource_dir
from llmnav.errors import PromptTemplateError

# The stepwise planner's system-prompt variants (docs/sources.md, A). "self-check" is the full prompt plus the
# `self_check` follow-up after every answer, so as a system prompt it resolves to `full`.
STEPWISE_VARIANTS = ("full", "short", "full_noconstraints", "short_noconstraints", "no_lidar_guidelines")
ALIASES = {"self-check": "full", "self_check_variant": "full"}
MAX_INCLUDE_DEPTH = 4

_NAME = re.compile(r"[A-Za-z0-9_]+")
_INCLUDE = re.compile(r"^[ \t]*<!--\s*include\s+(\S+?)\s*-->[ \t]*(?:\n|$)", re.MULTILINE)
_IF_BLOCK = re.compile(
    r"^[ \t]*<!--\s*if\s+(not\s+)?(\w+)\s*-->[ \t]*\n?(.*?)^[ \t]*<!--\s*endif\s*-->[ \t]*(?:\n|$)",
    re.MULTILINE | re.DOTALL,
)
_COMMENT_LINE = re.compile(r"^[ \t]*<!--.*?-->[ \t]*(?:\n|$)", re.MULTILINE | re.DOTALL)
_COMMENT = re.compile(r"<!--.*?-->", re.DOTALL)


def prompt_dir() -> Path:
    """The folder holding the bundled templates."""
    return resource_dir("prompts")


def _folder(package: str | None) -> Traversable:
    """The `prompts/` folder of `package` (None: llmnav's bundled one)."""
    if package is None:
        return prompt_dir()
    try:
        root = resources.files(package)
    except (ModuleNotFoundError, TypeError) as err:  # TypeError: a module, not a package
        raise PromptTemplateError(f"cannot read the prompts of package '{package}': {err}") from None
    folder = root / "prompts"
    if not folder.is_dir():
        raise PromptTemplateError(f"package '{package}' has no prompts/ folder")
    return folder


def _canonical(name: str) -> str:
    """Resolve aliases and CLI spellings (`full-noconstraints` -> `full_noconstraints`)."""
    name = name.strip()
    name = ALIASES.get(name, name).replace("-", "_")
    if not _NAME.fullmatch(name):
        raise PromptTemplateError(f"'{name}' is not a valid prompt template name")
    return name


def _read(folder: Traversable, name: str, what: str, package: str | None) -> str:
    path = folder / f"{name}.md"
    try:
        return path.read_text(encoding="utf-8")
    except FileNotFoundError:
        known = ", ".join(list_templates(package))
        raise PromptTemplateError(f"unknown {what} '{name}' (known templates: {known})") from None
    except (OSError, UnicodeDecodeError) as err:
        raise PromptTemplateError(f"cannot read {what} {path}: {err}") from None


def _expand(text: str, package: str | None, depth: int = 0) -> str:
    """Text with every include directive replaced by its part (recursively, to a fixed depth)."""

    def include(match: re.Match[str]) -> str:
        if depth >= MAX_INCLUDE_DEPTH:
            raise PromptTemplateError(f"prompt includes nest deeper than {MAX_INCLUDE_DEPTH} (a cycle?)")
        part = _canonical(match.group(1))
        body = _read(_folder(package) / "parts", part, "prompt part", package)
        return _expand(body if body.endswith("\n") else body + "\n", package, depth + 1)

    return _INCLUDE.sub(include, text)


def source(name: str, package: str | None = None) -> str:
    """A template's text with includes expanded (directives and placeholders still in place)."""
    canonical = _canonical(name)
    return _expand(_read(_folder(package), canonical, "prompt template", package), package)


def load_template(name: str, package: str | None = None) -> Template:
    """The template `name` as a `string.Template` (includes expanded; if-blocks resolved by `render`)."""
    return Template(source(name, package))


def template_hash(name: str, package: str | None = None) -> str:
    """SHA-256 (hex) of the template's text with its includes expanded: logged in the run config."""
    return hashlib.sha256(source(name, package).encode("utf-8")).hexdigest()


def list_templates(package: str | None = None) -> list[str]:
    """Names of all templates in the folder (llmnav's bundled one when `package` is None)."""
    folder = _folder(package)
    return sorted(entry.name[: -len(".md")] for entry in folder.iterdir() if entry.name.endswith(".md"))


def stepwise_variants() -> list[str]:
    """The stepwise system-prompt variants, plus `self-check` (full prompt + a follow-up per answer)."""
    return [*STEPWISE_VARIANTS, "self-check"]


def _as_text(value: Any) -> str:
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:g}"
    return str(value)


def render(name: str, package: str | None = None, **values: Any) -> str:
    """Fill template `name` (of `package`'s prompts/, default llmnav's) with `values`; unused values are ignored.

    Raises `PromptTemplateError` naming the template and the first missing placeholder or flag.
    """
    text = source(name, package)

    def choose(match: re.Match[str]) -> str:
        negate, flag, body = bool(match.group(1)), match.group(2), match.group(3)
        if flag not in values:
            raise PromptTemplateError(f"prompt template '{name}' needs a value for the flag '{flag}'")
        return body if bool(values[flag]) != negate else ""

    text = _IF_BLOCK.sub(choose, text)
    text = _COMMENT.sub("", _COMMENT_LINE.sub("", text))
    try:
        text = Template(text).substitute({k: _as_text(v) for k, v in values.items()})
    except KeyError as err:
        raise PromptTemplateError(f"prompt template '{name}' needs a value for '${err.args[0]}'") from None
    except ValueError as err:
        raise PromptTemplateError(f"prompt template '{name}' is malformed: {err}") from None
    return re.sub(r"\n{3,}", "\n\n", text).strip() + "\n"
