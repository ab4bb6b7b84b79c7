"""`llmnav transcribe`: print what a spoken command WAV says, normalised to the scenario's names."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from llmnav.commands.common import cli_errors, err_console, esc, print_data
from llmnav.errors import printable


def audio_task(path: Path, scenario: str | None, free: bool, *, quiet: bool = False) -> str:
    """Transcribe a task WAV for `drive`/`plan`; shows transcript and confidence unless quiet."""
    # deferred: speech recognition brings numpy (about 0.1 s), only for audio tasks
    from llmnav.sensing.voice import scenarios_for, transcribe

    transcript = transcribe(path, scenarios_for(scenario), free=free)
    if not quiet:
        confidence = "n/a" if transcript.confidence != transcript.confidence else f"{transcript.confidence:.2f}"
        err_console.print(
            f"heard: “{esc(transcript.words)}” → [bold]{esc(transcript.task_text)}[/] "
            f"(confidence {confidence}, {transcript.seconds:.2f} s)",
            highlight=False,
        )
    return transcript.task_text


@cli_errors
def transcribe(
    audio: Annotated[Path, typer.Argument(help="A PCM WAV file (any rate, mono or stereo).")],
    scenario: Annotated[str | None, typer.Option(help="Scenario whose names form the grammar (default: all).")] = None,
    asr_free: Annotated[bool, typer.Option("--asr-free", help="Open language model instead of the grammar.")] = False,
) -> None:
    """Print the task a spoken command names (nothing else, for scripts)."""
    print_data(printable(audio_task(audio, scenario, asr_free, quiet=True)))
