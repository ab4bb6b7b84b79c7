"""The tilt plug-in's own command: `llmnav tilt-report RUN_DIR` prints the turns a run made."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from llmnav.runs.runlog import read_run


def report(run_dir: Annotated[Path, typer.Argument(help="A run folder of the tilt planner.")]) -> None:
    """Print each turn a tilt run made, one line each."""
    for event in read_run(run_dir).of_type("tilt"):
        print(f"turned {event['turn_deg']:g} deg ({'model' if event['from_model'] else 'option'})")
