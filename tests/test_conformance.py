"""The conformance kit (llmnav.testing) on every registered planner and backend, on a third-party
planner that adds its own option, and on a whole plug-in (tests/plugin_fixture: its own prompt file, answer
model, option flag and command); plus the kit failing on planners and backends that break the contract."""

from __future__ import annotations

import re
from importlib.metadata import entry_points
from pathlib import Path
from typing import Any, ClassVar

import pytest
from pydantic import Field

from llmnav.backends.base import registry
from llmnav.planners.base import DriveOptions, EpisodeContext, EpisodeOutcome, Planner, planner_class
from llmnav.runs.runner import EpisodeSpec, run_episode
from llmnav.testing import check_backend, check_planner

SMALL = str(Path(__file__).parent / "runner" / "small_room.yaml")
# Where a planner needs a scenario of its kind: signs for the FSM, a published map for waypoints.
SCENARIO = {"fsm": ("maze_arena", {"max_ticks": 100}), "waypoints": ("corridor_a", {})}


@pytest.mark.parametrize("name", sorted(ep.name for ep in entry_points(group="llmnav.planners")))
def test_every_registered_planner_conforms(name: str) -> None:
    scenario, options = SCENARIO.get(name, (SMALL, {}))
    check_planner(planner_class(name), scenario=scenario, options=options)


@pytest.fixture(scope="module")
def recorded_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("recorded") / "run"
    spec = EpisodeSpec(
        scenario=SMALL, task_id="T1", options={"planner": "hybrid", "max_iterations": 2}, backend="policy:first",
        out_dir=out, plots=False,
    )  # fmt: skip
    run_episode(spec)
    return out


@pytest.mark.parametrize("name", sorted(registry()))
def test_every_registered_backend_conforms(name: str, recorded_run: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    for key in ("GEMINI_API_KEY", "OPENAI_API_KEY"):
        monkeypatch.setenv(key, "test-key")  # constructed only: no request leaves the process
    # HTTP backends are only constructed (no request is sent); the port is a closed loopback one.
    args = {
        "replay": str(recorded_run), "policy": "first", "openai": "m@http://127.0.0.1:9/v1",
        "ollama": "m@http://127.0.0.1:9", "gemini": "m@http://127.0.0.1:9",
    }  # fmt: skip
    check_backend(registry()[name], args.get(name))


class LeanOptions(DriveOptions):
    """A third party's own option."""

    lean_deg: float = Field(default=10.0, ge=0, le=45, description="[deg] how far the robot leans")


class LeanPlanner(Planner[LeanOptions]):
    """Turns in place by its own option, then stops: ten lines of a plug-in."""

    name: ClassVar[str] = "lean"
    needs_backend: ClassVar[bool] = False
    Options: ClassVar[type[LeanOptions]] = LeanOptions
    grid_factors: ClassVar[tuple[str, ...]] = ("lean_deg",)

    def run(self, ctx: EpisodeContext[LeanOptions]) -> EpisodeOutcome:
        ctx.world.motion.rotate(ctx.options.lean_deg * 3.14159 / 180.0)
        ctx.event("lean", lean_deg=ctx.options.lean_deg)
        return EpisodeOutcome("completed", "leaned", iterations=1)


@pytest.fixture
def lean_registered(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """`lean` registered under llmnav.planners by a dist-info folder on sys.path (as `pip install` would)."""
    dist = tmp_path / "lean_plugin-1.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: lean-plugin\nVersion: 1.0\n")
    (dist / "entry_points.txt").write_text("[llmnav.planners]\nlean = tests.test_conformance:LeanPlanner\n")
    monkeypatch.syspath_prepend(str(tmp_path))


def test_a_third_party_planner_with_its_own_option_conforms(lean_registered: None, tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from llmnav.cli import app
    from llmnav.runs.runlog import read_run

    check_planner(LeanPlanner, scenario=SMALL)
    out = tmp_path / "run"
    result = CliRunner().invoke(
        app, ["drive", "--scenario", SMALL, "--task-id", "T1", "--planner", "lean", "-o", "lean_deg=30", "--out",
              str(out), "--quiet"],
    )  # fmt: skip
    assert result.exit_code in (0, 1), result.output
    events = read_run(out).of_type("lean")
    assert [e["lean_deg"] for e in events] == [30.0]
    assert read_run(out).config["options"]["lean_deg"] == 30.0
    bad = CliRunner().invoke(app, ["drive", "--scenario", SMALL, "--task-id", "T1", "--planner", "lean", "-o",
                                   "lean_deg=90", "--out", str(tmp_path / "bad")])  # fmt: skip
    assert bad.exit_code == 2 and "-o lean_deg" in bad.output and "45" in bad.output, bad.output


def test_the_kit_refuses_an_unregistered_class_and_an_option_without_a_unit(lean_registered: None) -> None:
    from unittest import mock

    from llmnav import testing

    class Unitless(LeanOptions):
        speed: float = 1.0

    class Sloppy(LeanPlanner):
        Options: ClassVar[type[LeanOptions]] = Unitless

    with pytest.raises(AssertionError, match="entry point names another class"):
        check_planner(Sloppy, scenario=SMALL)
    with mock.patch("llmnav.planners.base.planner_class", return_value=Sloppy):
        with pytest.raises(AssertionError, match="'speed' has no description"):
            testing.check_planner(Sloppy, scenario=SMALL)


def test_the_kit_refuses_a_backend_that_accepts_any_option() -> None:
    from llmnav.backends.policy import PolicyBackend

    class Lenient(PolicyBackend):
        def __init__(self, arg: str | None = None, **options: Any) -> None:
            super().__init__(arg)

    with pytest.raises(AssertionError, match="was accepted"):
        check_backend(Lenient, "first")


def test_the_kit_finds_a_raw_simulator_handle_behind_public_attributes() -> None:
    from llmnav import testing

    raw = type("World", (), {"__module__": "llmnav.sim.world"})()
    holder = type("Holder", (), {})()
    holder.inner = {"handles": [raw]}
    holder._private = raw  # private names are the layer's own business
    assert [path for path, _ in testing._raw_handles(holder)] == ["ctx.inner['handles'][0]"]


PLUGIN_FIXTURE = Path(__file__).parent / "plugin_fixture"  # the `tiltplug` package: see its README


@pytest.fixture
def tilt_installed(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The `tiltplug` distribution installed for one test: its package and a dist-info naming its entry points."""
    dist = tmp_path / "tiltplug-0.3.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: tiltplug\nVersion: 0.3\n")
    (dist / "entry_points.txt").write_text(
        "[llmnav.planners]\ntilt = tiltplug:TiltPlanner\n\n[llmnav.commands]\ntilt-report = tiltplug.command:report\n"
    )
    monkeypatch.syspath_prepend(str(PLUGIN_FIXTURE))
    monkeypatch.syspath_prepend(str(tmp_path))


def test_a_third_party_planner_ships_its_prompts_answers_flag_and_command(
    tilt_installed: None, tmp_path: Path
) -> None:
    """A plug-in llmnav never names runs through the kit, `drive --tilt`, `ablate --tilt` and its own command."""
    from typer.testing import CliRunner

    from llmnav.cli import make_app
    from llmnav.planners import prompting
    from llmnav.runs.runlog import read_run

    tilt = planner_class("tilt")
    check_planner(tilt, scenario=SMALL)
    app = make_app()
    out = tmp_path / "run"
    drive = ["drive", "--scenario", SMALL, "--task-id", "T1", "--planner", "tilt", "--backend", "policy:first"]
    result = CliRunner().invoke(app, [*drive, "--tilt", "30", "--out", str(out), "--quiet"])
    assert result.exit_code in (0, 1), result.output
    run = read_run(out)
    # its own prompt file, from its own package: sent to the model and hashed into the config line
    (call,) = run.of_type("llm_call")
    system = call["request"]["messages"][0]["text"]
    assert system.startswith("You steer a robot that can only turn in place (tilt plug-in).\nThe task: ")
    assert run.config["prompt_hashes"] == {"tilt_system": prompting.template_hash("tilt_system", "tiltplug")}
    # its answer model: the null policy's answer read through it; the flag reached its option
    (turn,) = run.of_type("tilt")
    assert turn["from_model"] is True and -45 <= turn["turn_deg"] <= 45
    assert run.config["options"]["tilt_deg"] == 30.0
    # its flag fails like a built-in one, naming the flag
    bad = CliRunner().invoke(app, [*drive, "--tilt", "90", "--out", str(tmp_path / "bad")])
    assert bad.exit_code == 2 and "--tilt" in bad.output and "45" in bad.output, bad.output
    # ablate takes it as a factor
    sweep = ["ablate", "--scenario", SMALL, "--planner", "tilt", "--tasks", "T1", "--poses", "1", "--tilt", "5,20"]
    plan = CliRunner().invoke(app, [*sweep, "--dry-run", "--out", str(tmp_path / "sweep")])
    assert plan.exit_code == 0, plan.output
    assert "2 episodes (planner: 1, tilt_deg: 2; trials: 1)" in plan.output, plan.output
    # its command
    report = CliRunner().invoke(app, ["tilt-report", str(out)])
    assert report.exit_code == 0 and report.output.startswith("turned "), report.output


def test_nothing_in_llmnav_names_the_plugin() -> None:
    package = Path(__file__).parents[1] / "llmnav"
    names = re.compile(r"\btilt\b|tiltplug|tilt_deg|tilt-report", re.IGNORECASE)  # its names, not the word "tilted"
    named = [str(p) for p in package.rglob("*.py") if names.search(p.read_text(encoding="utf-8"))]
    assert not named, named
