"""What every command shares: the consoles, safe printing, and the translation of errors into one line.

Safe printing: everything shown that came from a user file, a model or a server goes through `esc`
(control characters made visible, Rich markup escaped), so a task text cannot retitle or clear the
terminal and a `[/]` in a path cannot crash or eat the message. Machine-readable output (`print_data`)
is written as is, never wrapped: it does not depend on the terminal width, and `COLUMNS=0` (or any
nonsense width) is ignored. A reader that goes away (`llmnav ... | head -1`) ends the output, not the
command: the run's exit code stands.
"""

from __future__ import annotations

import errno
import functools
import io
import json
import os
import sys
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Annotated, Any, ParamSpec, TypeVar

import typer
from rich.console import Console

from llmnav.errors import BadInputError, LlmnavError, one_line, printable
from llmnav.reporting.safe import esc

__all__ = [
    "OutputError",
    "chart_folder_option",
    "check_output_path",
    "cli_errors",
    "console",
    "err_console",
    "esc",
    "fail",
    "listing_format",
    "print_listing",
    "print_table",
    "parse_option_pairs",
    "path_option",
    "plot_option",
    "print_data",
    "stdout",
]

P = ParamSpec("P")
R = TypeVar("R")


class _ConsoleEnviron(Mapping[str, str]):
    """os.environ as Rich reads it, minus a COLUMNS or LINES that is not a positive number.

    Live, not a copy: a caller (or a test) may change the environment. COLUMNS=0 made every line, JSON
    included, zero characters wide.
    """

    def _bad(self, key: str) -> bool:
        value = os.environ.get(key) if key in ("COLUMNS", "LINES") else None
        return value is not None and not (value.strip().isdigit() and int(value) > 0)

    def __getitem__(self, key: str) -> str:
        if self._bad(key):
            raise KeyError(key)
        return os.environ[key]

    def __iter__(self) -> Iterator[str]:
        return (key for key in os.environ if not self._bad(key))

    def __len__(self) -> int:
        return sum(1 for _ in self)


class OutputError(LlmnavError):
    """Standard output cannot be written (disk full, I/O error)."""


class _Stdout(io.TextIOBase):
    """`sys.stdout` (looked up at each write, so test runners may swap it) that survives its reader.

    A closed pipe silences the rest of the output; any other write error (a full disk) becomes one
    `OutputError`. Either way the real stdout is pointed at /dev/null so Python's exit flush is quiet.
    """

    def __init__(self) -> None:
        self.reader_gone = False

    def _silence(self) -> None:
        try:
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, sys.stdout.fileno())
            os.close(devnull)
        except (OSError, ValueError, io.UnsupportedOperation):
            pass

    def _guard(self, action: Callable[[], object]) -> None:
        if self.reader_gone:
            return
        try:
            action()
        except BrokenPipeError:
            self.reader_gone = True
            self._silence()
        except OSError as err:
            self.reader_gone = True
            self._silence()
            if err.errno == errno.EPIPE:
                return
            raise OutputError(f"cannot write to standard output: {err.strerror or err}") from None

    def write(self, text: str) -> int:
        self._guard(lambda: sys.stdout.write(text))
        return len(text)

    def flush(self) -> None:
        self._guard(sys.stdout.flush)

    def isatty(self) -> bool:
        try:
            return sys.stdout.isatty()
        except (ValueError, AttributeError):
            return False

    def fileno(self) -> int:
        return sys.stdout.fileno()

    @property
    def encoding(self) -> str:  # type: ignore[override]
        return getattr(sys.stdout, "encoding", None) or "utf-8"

    def writable(self) -> bool:
        return True


stdout = _Stdout()
console = Console(file=stdout, _environ=_ConsoleEnviron())  # type: ignore[arg-type]
err_console = Console(stderr=True, _environ=_ConsoleEnviron())


# Options that serve every backend the same way in `drive` and `ablate`: declared once here.
DropImagesOption = Annotated[
    bool, typer.Option("--drop-images", help="A server that takes no images: go on without them.")
]
CacheOption = Annotated[
    str | None,
    typer.Option("--cache", help="Reply cache folder for HTTP backends: a repeated request is not sent again."),
]
PricesOption = Annotated[
    str | None,
    typer.Option("--prices", help="Price table (TOML) for cost_usd; default $LLMNAV_PRICES, else the bundled one."),
]


def print_data(text: str) -> None:
    """Machine-readable output (JSON, CSV): written as is, a newline added, never wrapped or styled."""
    stdout.write(text if text.endswith("\n") else text + "\n")
    stdout.flush()


LISTING_FORMATS = ("table", "tsv", "json")


def listing_format(text: str) -> str:
    """A listing's `--format`, checked before any work."""
    if text not in LISTING_FORMATS:
        raise BadInputError(f"--format {text!r}: expected {', '.join(LISTING_FORMATS[:-1])} or {LISTING_FORMATS[-1]}")
    return text


def _tsv_cell(value: Any) -> str:
    """One TSV cell: lists joined by commas, None empty, tabs and line breaks made spaces (one line a row)."""
    if value is None:
        return ""
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, list | tuple):
        return ",".join(_tsv_cell(v) for v in value)
    return " ".join(printable(str(value)).replace("\t", " ").splitlines())


def print_listing(output_format: str, records: Sequence[Mapping[str, Any]], table: Any) -> None:
    """A listing on stdout: `table` (rich, never cut when piped), or only data as `json` or `tsv`.

    `tsv` is a header line of the records' keys and one line per record, for `cut`, `awk` and `grep`.
    """
    if output_format == "json":
        print_data(json.dumps(list(records), indent=2))
    elif output_format == "tsv":
        columns = list(dict.fromkeys(key for record in records for key in record))
        lines = ["\t".join(columns)]
        lines += ["\t".join(_tsv_cell(record.get(column)) for column in columns) for record in records]
        print_data("\n".join(lines))
    else:
        print_table(table)


def print_table(table: Any) -> None:
    """A rich table on stdout: fitted to a terminal, at its full width in a pipe or file (never cut)."""
    # deferred: the table printer (about 5 ms) loads only when a table is printed, not for `llmnav --help`
    from llmnav.reporting.tables import print_unsqueezed

    print_unsqueezed(console, table)


def path_option(text: str | None, flag: str) -> Path | None:
    """A path flag given as text: an empty one is refused (Path("") would be the working directory)."""
    if text is None:
        return None
    if not text.strip():
        raise BadInputError(f"{flag}: empty path; give a file or folder name")
    return Path(text)


PLOT_FORMATS = (".png", ".pdf", ".svg")


def plot_option(text: str | None, flag: str = "--plot") -> Path | None:
    """A figure path checked before any work: a file name (not a folder) with a format matplotlib writes.

    No suffix means PNG, and the suffix is added here, so the path reported is the path written.
    """
    path = path_option(text, flag)
    if path is None or text is None:
        return None
    if text.endswith(("/", os.sep)) or path.is_dir():
        raise BadInputError(f"{flag} {text}: a folder; give a file name such as {path / 'plot.png'}")
    if not path.suffix:
        path = path.with_name(path.name + ".png")
    elif path.suffix.lower() not in PLOT_FORMATS:
        raise BadInputError(f"{flag} {text}: cannot draw a '{path.suffix}' file; use {', '.join(PLOT_FORMATS)}")
    if path.parent.exists() and not path.parent.is_dir():
        raise BadInputError(f"{flag} {text}: {path.parent} is not a folder")
    check_output_path(path, flag)
    return path


def chart_folder_option(path: Path | None, flag: str = "--plot") -> None:
    """Refuse a file-like name for an option that is a folder of charts (it would become a folder)."""
    if path is not None and (path.suffix.lower() in PLOT_FORMATS or (path.exists() and not path.is_dir())):
        raise BadInputError(f"{flag} {path}: the charts go into a folder; give a folder name such as 'charts'")


def check_output_path(out: Path, flag: str, inputs: Sequence[Path] = ()) -> None:
    """Refuse to write `out` onto an input, or anywhere inside a run folder (its log, summary, images)."""
    # deferred: the run log module (about 14 ms with its imports), not for `llmnav --help`
    from llmnav.runs.runlog import RUN_FILE

    target = out.absolute()
    for given in inputs:
        given = Path(given).absolute()
        if target == given or (given.is_dir() and target == given / RUN_FILE):
            raise BadInputError(f"{flag} {out}: that is an input; choose another file")
    for folder in (target, *target.parents):
        if (folder / RUN_FILE).is_file() and folder != target:
            raise BadInputError(f"{flag} {out}: inside the run folder {folder}; choose a file outside it")


def fail(message: str, code: int = 2) -> typer.Exit:
    """Print a one-line error and return the Exit to raise.

    The message is escaped: it may quote a path, a model or a server.
    """
    err_console.print(f"[bold red]error:[/] {esc(message)}", highlight=False, soft_wrap=True)
    return typer.Exit(code)


def cli_errors(func: Callable[P, R]) -> Callable[P, R]:
    """Turn llmnav errors into one line on stderr and their exit code; Ctrl-C into exit 130."""

    @functools.wraps(func)
    def wrapper(*args: P.args, **kwargs: P.kwargs) -> R:
        try:
            return func(*args, **kwargs)
        except LlmnavError as err:
            raise fail(one_line(err), err.exit_code) from None
        except KeyboardInterrupt:
            raise fail("interrupted; everything written so far is kept", 130) from None

    return wrapper


def parse_sensing(text: str) -> tuple[str, ...]:
    """`--sensing lidar,image`: the comma list as a tuple (each at most once; the names are checked by the caller)."""
    parts = tuple(s.strip() for s in text.split(",") if s.strip())
    repeated = sorted({s for s in parts if parts.count(s) > 1})
    if repeated:
        raise BadInputError(f"--sensing {text!r}: lists {', '.join(repeated)} more than once")
    return parts


def parse_option_pairs(pairs: list[str] | None) -> dict[str, str]:
    """`-o KEY=VALUE` (repeatable) as a mapping; the planner's options model checks keys and values."""
    given: dict[str, str] = {}
    for pair in pairs or []:
        key, sep, value = pair.partition("=")
        key = key.strip().replace("-", "_")
        if not sep or not key.isidentifier():
            raise BadInputError(f"-o {pair!r}: expected KEY=VALUE, e.g. -o max_iterations=10")
        if key == "planner":
            raise BadInputError("-o planner: give the planner with --planner")
        if key in given:  # one would silently win: refused, as a YAML key given twice is
            raise BadInputError(f"-o {key} is given twice ({given[key]!r} and {value.strip()!r}); give it once")
        given[key] = value.strip()
    return given
