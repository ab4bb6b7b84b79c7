"""Commands that installed distributions register under `llmnav.commands`: added, refused on a clash, listed
when broken, and never breaking the other commands."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from llmnav.cli import COMMAND_GROUP, make_app

COMMANDS = '''
import typer


def hello(name: str = typer.Option("robot", help="Who is greeted.")) -> None:
    """Greet someone (a plugin's command)."""
    print(f"hello {name}")


NOT_A_COMMAND = 42
'''


def _install(site: Path, dist: str, lines: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """A distribution `dist` with `lines` under llmnav.commands, on sys.path as `pip install` leaves it."""
    info = site / f"{dist}-1.0.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {dist}\nVersion: 1.0\n", encoding="utf-8")
    (info / "entry_points.txt").write_text(f"[{COMMAND_GROUP}]\n{lines}\n", encoding="utf-8")
    monkeypatch.syspath_prepend(str(site))


@pytest.fixture
def site(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    (tmp_path / "hello_commands.py").write_text(COMMANDS, encoding="utf-8")
    monkeypatch.syspath_prepend(str(tmp_path))
    return tmp_path


def test_a_plugin_command_is_added(site: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    _install(site, "hello-plugin", "hello = hello_commands:hello", monkeypatch)
    result = CliRunner().invoke(make_app(), ["hello", "--name", "rover"])
    assert result.exit_code == 0 and result.output == "hello rover\n", result.output


def test_a_clash_with_a_built_in_is_refused_naming_both(site: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    _install(site, "grabby", "drive = hello_commands:hello", monkeypatch)
    app = make_app()
    listing = CliRunner().invoke(app, ["--help"], terminal_width=400)
    assert "command 'drive' of grabby 1.0 (hello_commands:hello) clashes with the built-in command 'drive' " in (
        " ".join(listing.output.replace("│", " ").split())
    ), listing.output
    assert "llmnav.commands.drive:drive" in " ".join(listing.output.replace("│", " ").split())
    drive_help = CliRunner().invoke(app, ["drive", "--help"])
    assert drive_help.exit_code == 0 and "--task-id" in drive_help.output  # the built-in is kept


def test_the_built_in_commands_own_registration_is_no_clash(site: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    _install(site, "llmnav-again", "plan = llmnav.planners.waypoints.command:plan", monkeypatch)
    app = make_app()
    assert "Refused" not in CliRunner().invoke(app, ["--help"], terminal_width=400).output
    assert CliRunner().invoke(app, ["plan", "--help"]).exit_code == 0


def test_a_broken_command_is_listed_and_troubles_no_other(site: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    _install(
        site, "shaky", "gone = no_such_module_xyz:run\nnumber = hello_commands:NOT_A_COMMAND\n"
        "hello = hello_commands:hello", monkeypatch,
    )  # fmt: skip
    app = make_app()
    gone = CliRunner().invoke(app, ["gone"])
    assert gone.exit_code == 2, gone.output
    lines = [line for line in gone.output.splitlines() if line.strip()]
    assert len(lines) == 1 and "command 'gone' from shaky 1.0 failed to load: ModuleNotFoundError" in lines[0]
    number = CliRunner().invoke(app, ["number"])
    assert number.exit_code == 2 and "is not a command: int" in number.output, number.output
    listing = CliRunner().invoke(app, ["--help"], terminal_width=400)
    assert "gone" in listing.output and "broken" in listing.output
    assert CliRunner().invoke(app, ["hello"]).output == "hello robot\n"
    assert CliRunner().invoke(app, ["planners", "--help"]).exit_code == 0


def test_two_plugins_one_name_are_refused_naming_both(site: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    _install(site / "a", "first-plugin", "hello = hello_commands:hello", monkeypatch)
    _install(site / "b", "second-plugin", "hello = hello_commands:NOT_A_COMMAND", monkeypatch)
    result = CliRunner().invoke(make_app(), ["hello"])
    assert result.exit_code == 2
    text = " ".join(result.output.split())
    assert "first-plugin 1.0" in text and "second-plugin 1.0" in text, text
