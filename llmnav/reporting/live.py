"""What the user sees during `llmnav drive`: a rich live table per step, or one progress line (`--quiet`).

Both are `View`s (llmnav.planners.base) and context managers; `--json` uses `NullView` and prints nothing
until the end. `print_result` shows the outcome, score, path length and run folder.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Literal

from rich.console import Console, Group
from rich.live import Live
from rich.table import Table
from rich.text import Text

from llmnav.errors import printable
from llmnav.planners.base import StepInfo
from llmnav.reporting.safe import esc

if TYPE_CHECKING:
    from llmnav.runs.runner import EpisodeSpec

MAX_ROWS = 12  # rows kept on screen; older steps scroll away
REASONING_CHARS = 70
COLUMNS: list[tuple[str, Literal["left", "right"]]] = [
    ("step", "right"),
    ("action", "left"),
    ("reasoning", "left"),
    ("front", "right"),
    ("latency", "right"),
    ("vetoes", "right"),
    ("JSON retries", "right"),
]


def _fmt(value: float | None, unit: str, digits: int = 2) -> str:
    return "–" if value is None else f"{value:.{digits}f} {unit}"


def _first_line(text: str, limit: int = REASONING_CHARS) -> str:
    line = printable(" ".join(text.split()))
    return line if len(line) <= limit else line[: limit - 1] + "…"


class LiveView:
    """A live table: step, action, one line of reasoning, front distance, latency, vetoes, JSON retries."""

    def __init__(self, console: Console, spec: EpisodeSpec) -> None:
        self.console = console
        task = spec.task_id or spec.task_text or ""
        self.title = printable(f"{spec.options.planner} · {spec.scenario} · {task}")
        self.rows: list[StepInfo] = []
        self._live = Live(self._render(), console=console, refresh_per_second=8, transient=False)

    def _render(self) -> Group:
        rows = self.rows[-MAX_ROWS:]
        cells = [
            (
                str(info.step),
                _first_line(info.action),
                _first_line(info.reasoning),
                _fmt(info.front_m, "m"),
                _fmt(info.latency_s, "s"),
                str(info.vetoes) if info.vetoes else "",
                str(info.json_retries) if info.json_retries else "",
            )
            for info in rows
        ]
        # A column no planner fills (no reasoning from the oracle, no latency without a model) is left out.
        shown = [i for i in range(len(COLUMNS)) if i < 2 or any(c[i] not in ("", "–") for c in cells)]
        table = Table(expand=False)
        for i in shown:
            name, justify = COLUMNS[i]
            table.add_column(name, justify=justify, overflow="fold")
        for row in cells:  # model text: plain Text (never markup), control characters already escaped
            table.add_row(*(Text(row[i]) for i in shown))
        return Group(Text(self.title, style="bold"), table)

    def on_step(self, info: StepInfo) -> None:
        """Add a row and redraw (the display starts with the first step, so bad input prints no table)."""
        self.rows.append(info)
        self._live.update(self._render())
        self._live.start()

    def __enter__(self) -> LiveView:
        return self

    def __exit__(self, *exc: object) -> None:
        if self._live.is_started:
            self._live.stop()
            if not self.console.is_terminal:  # a redirected live view ends without a line break
                self.console.line()


class ProgressView:
    """One line, rewritten each step (`--quiet`)."""

    def __init__(self, console: Console, max_iterations: int) -> None:
        self.max_iterations = max_iterations
        self._live = Live(Text(""), console=console, refresh_per_second=4, transient=True)

    def on_step(self, info: StepInfo) -> None:
        """Replace the line."""
        action = _first_line(info.action)
        line = f"step {info.step}/{self.max_iterations}  {action}  front {_fmt(info.front_m, 'm')}"
        if info.latency_s is not None:
            line += f"  model {info.latency_s:.1f} s"
        self._live.update(Text(line))
        self._live.start()

    def __enter__(self) -> ProgressView:
        return self

    def __exit__(self, *exc: object) -> None:
        self._live.stop()


def cost_text(summary: dict[str, Any]) -> str:
    """ "cost 0.0048 USD (2 model calls, 1 from the cache)", or "cost unknown (why)"."""
    cost, calls, hits = summary.get("cost_usd"), summary.get("llm_calls"), summary.get("cache_hits") or 0
    cached = f", {hits} from the cache" if hits else ""
    if isinstance(cost, (int, float)):
        return f"cost {cost:.4f} USD ({calls} model call(s){cached})"
    note = str(summary.get("cost_note") or "").removeprefix("unknown: ")
    return f"cost unknown ({note}; {calls} model call(s){cached})"


def print_result(console: Console, summary: dict[str, Any]) -> None:
    """The end of a drive: outcome and reason, score, path length, run folder, plot."""
    outcome = str(summary.get("outcome"))
    colour = {"completed": "green", "failed": "yellow", "not_found": "yellow"}.get(outcome, "red")
    reason = summary.get("reason") or ""
    console.print(f"[bold {colour}]{esc(outcome)}[/]" + (f" — {esc(reason)}" if reason else ""), highlight=False)
    score = summary.get("score")
    if outcome == "aborted":  # the final pose of a run cut off by an error is no result
        parts = ["no score (aborted)"]
    else:
        parts = [
            f"score {score:.2f}" if isinstance(score, (int, float)) else "score N.A.",
            f"success {'yes' if summary.get('success') else 'no'}",
        ]
    parts += [
        f"path {summary.get('path_length_m', 0.0):.2f} m",
        f"iterations {summary.get('iterations')}",
    ]
    if summary.get("distance_m") is not None and outcome != "aborted":
        parts.append(f"distance to target {summary['distance_m']:.2f} m")
    console.print("  ".join(parts), highlight=False)
    if summary.get("llm_calls"):
        console.print(esc(cost_text(summary)), highlight=False, soft_wrap=True)
    console.print(f"run folder: {esc(summary.get('run_dir'))}", highlight=False, soft_wrap=True)
    if summary.get("trajectory"):
        console.print(f"trajectory: {esc(summary['trajectory'])}", highlight=False, soft_wrap=True)
