"""A planner's own flags: declared on its options (`CliFlag`), built for `drive` and `ablate` in one place."""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path

import pytest
from typer.testing import CliRunner

from llmnav.cli import make_app
from llmnav.commands.planner_flags import declared_flags, flag_of
from llmnav.planners.base import planner_class, usable_planner_names

COMMANDS = Path(__file__).parents[1] / "llmnav" / "commands"
SMALL = str(Path(__file__).parent / "runner" / "small_room.yaml")


def _help(command: str) -> str:
    result = CliRunner().invoke(make_app(), [command, "--help"], terminal_width=400)
    assert result.exit_code == 0, result.output
    return " ".join(result.output.replace("│", " ").split())


def test_no_command_spells_a_flag_of_a_single_planner() -> None:
    flags = {f.flag for name in usable_planner_names() for f in planner_class(name).Options.cli_flags}
    assert flags  # the built-in planners declare some
    for source in COMMANDS.glob("*.py"):
        text = source.read_text(encoding="utf-8")
        spelled = sorted(f for f in flags if re.search(re.escape(f) + r"\b", text))
        assert not spelled, f"{source.name} spells {spelled}"


def test_drive_and_ablate_offer_every_declared_flag_with_its_help() -> None:
    drive, ablate = _help("drive"), _help("ablate")
    for flag in declared_flags(sweep=False):
        assert f"{flag.flag} " in drive, flag.flag
        shown = flag.help.split("[")[0].strip()  # rich drops a [default: ...] note, as it always did
        assert shown in drive, shown
        if flag.sweep is None:
            assert f"{flag.flag} " not in ablate, flag.flag
        else:
            assert (flag.sweep_help or flag.help).split("[")[0].strip() in ablate, flag.flag


def test_an_error_names_the_flag_that_set_a_derived_field() -> None:
    assert flag_of("ttl_ms") == "--ttl" and flag_of("menu_order") == "--menu-order" and flag_of("seed") is None
    result = CliRunner().invoke(make_app(), ["drive", "--planner", "fsm", "--task-id", "T1", "--ttl", "-5",
                                             "--backend", "policy:first", "--out", "/nonexistent/never"])  # fmt: skip
    assert result.exit_code == 2, result.output
    assert result.output.count("\n") == 1 and "--ttl:" in result.output, result.output


def test_a_plugin_adds_a_flag_and_cannot_take_one_that_exists(
    install_planner: Callable[[str, str, str], None],
) -> None:
    install_planner("knob", "knob_planner:KnobPlanner", KNOB)
    by_flag = {f.flag: f for f in declared_flags(sweep=False)}
    assert by_flag["--knob"].key == "knob_m"
    assert by_flag["--assist"].key == "assist"  # `fsm` declares it first: the plug-in's is left out
    drive = _help("drive")
    assert "--knob " in drive and "Knob length in metres." in drive
    assert "Takes a flag another planner declared." not in drive and "Takes a flag drive has." not in drive
    assert drive.count("--seed ") == 1 and "Simulation and model seed." in drive
    assert "--knob " not in _help("ablate")  # no sweep declared


KNOB = '''
from typing import ClassVar

from pydantic import Field

from llmnav.planners.base import CliFlag, DriveOptions, EpisodeOutcome, Planner


class KnobOptions(DriveOptions):
    knob_m: float = Field(default=1.0, description="[m] a knob")
    other: str = Field(default="x", description="a second knob")
    seed_text: str = Field(default="", description="a third")
    cli_flags: ClassVar[tuple[CliFlag, ...]] = (
        CliFlag("--knob", "knob_m", "Knob length in metres."),
        CliFlag("--assist", "other", "Takes a flag another planner declared."),
        CliFlag("--seed", "seed_text", "Takes a flag drive has."),
    )


class KnobPlanner(Planner[KnobOptions]):
    name: ClassVar[str] = "knob"
    needs_backend: ClassVar[bool] = False
    Options: ClassVar[type[KnobOptions]] = KnobOptions

    def run(self, ctx):
        return EpisodeOutcome("completed", "nothing to do", iterations=0)
'''


@pytest.mark.parametrize("command", ["drive", "ablate"])
def test_drive_flags_in_help_keep_their_order_of_own_then_planners(command: str) -> None:
    text = _help(command)
    assert text.index("--backend ") < text.index("--assist ") < text.index("--help ")
