"""`llmnav scenarios generate` on the command line: a file on success; one line, exit 2 and no file otherwise."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from llmnav.buildings.generate import Request, generate
from llmnav.cli import app
from llmnav.world.scenario import load_scenario


def generate_text(kind: str, seed: int) -> str:
    return generate(Request(kind, seed)).text


def invoke(*args: str) -> tuple[int, str]:
    result = CliRunner().invoke(app, list(args))
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    return result.exit_code, result.output


def test_the_command_writes_the_same_file_twice(tmp_path: Path) -> None:
    first, second = tmp_path / "a.yaml", tmp_path / "b.yaml"
    for path in (first, second):
        code, output = invoke("scenarios", "generate", "--kind", "warehouse", "--seed", "11", "-o", str(path))
        assert code == 0, output
    assert first.read_bytes() == second.read_bytes()
    assert load_scenario(first).name == "warehouse-11"
    code, output = invoke("scenarios", "check", str(first))
    assert code == 0, output


IMPOSSIBLE = [
    (["--kind", "castle"], "unknown building kind 'castle' (kinds: flat, office, warehouse)"),
    (["--kind", "flat", "--rooms", "0"], "at least 1 room"),
    (["--kind", "flat", "--rooms", "9"], "at most 8 rooms"),
    (["--kind", "office", "--rooms", "15"], "at most 14 rooms"),
    (["--kind", "flat", "--rooms", "6", "--size", "6x5"], "cannot hold 6 rooms"),
    (["--kind", "office", "--rooms", "9", "--size", "12x12"], "cannot be cut into 9 rooms"),
    (["--kind", "flat", "--size", "12 by 9"], "expected WIDTHxDEPTH"),
    (["--kind", "flat", "--size", "200x9"], "between 4 and 80 m"),
    (["--kind", "flat", "--size", "nanx9"], "finite"),
    (["--kind", "flat", "--starts", "0"], "--starts 0"),
    (["--kind", "flat", "--robot", "tank"], "unknown robot"),
    (["--kind", "flat", "--seed", "-1"], "seeds are 0 or more"),
]


@pytest.mark.parametrize(("args", "needle"), IMPOSSIBLE, ids=[" ".join(a) for a, _ in IMPOSSIBLE])
def test_impossible_requests_write_nothing(tmp_path: Path, args: list[str], needle: str) -> None:
    out = tmp_path / "b.yaml"
    seed = [] if "--seed" in args else ["--seed", "1"]
    code, output = invoke("scenarios", "generate", *args, *seed, "-o", str(out))
    assert code == 2, output
    assert len(output.strip().splitlines()) == 1 and output.startswith("error:"), output
    assert needle in output, output
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_an_existing_file_is_kept_when_the_request_is_impossible(tmp_path: Path) -> None:
    out = tmp_path / "b.yaml"
    out.write_text("kept\n", encoding="utf-8")
    code, _ = invoke("scenarios", "generate", "--kind", "flat", "--rooms", "0", "--seed", "1", "-o", str(out))
    assert code == 2 and out.read_text(encoding="utf-8") == "kept\n"


def test_the_output_must_be_a_yaml_file_name(tmp_path: Path) -> None:
    for out, needle in ((tmp_path / "b.txt", "ends in .yaml"), (tmp_path, "ends in .yaml")):
        code, output = invoke("scenarios", "generate", "--kind", "flat", "--seed", "1", "-o", str(out))
        assert code == 2 and needle in output, output


def test_a_suite_is_a_folder_of_buildings_that_check_passes(tmp_path: Path) -> None:
    suite = tmp_path / "suite"
    code, output = invoke("scenarios", "generate", "--kind", "flat", "--seed", "5", "--count", "3", "-o", str(suite))
    assert code == 0, output
    names = sorted(p.name for p in suite.iterdir())
    assert names == ["flat-5.yaml", "flat-6.yaml", "flat-7.yaml"]
    assert (suite / "flat-6.yaml").read_text(encoding="utf-8") == generate_text("flat", 6)
    code, output = invoke("scenarios", "check", str(suite))
    assert code == 0 and output.count(": ok") == 3, output


def test_a_suite_too_large_or_into_a_file_is_refused(tmp_path: Path) -> None:
    file = tmp_path / "x.yaml"
    file.write_text("x", encoding="utf-8")
    cases = ((tmp_path / "s", "0", "1 to 1000"), (tmp_path / "s", "1001", "1 to 1000"), (file, "2", "a folder"))
    for out, count, needle in cases:
        args = ["--kind", "flat", "--seed", "1", "--count", count, "-o", str(out)]
        code, output = invoke("scenarios", "generate", *args)
        assert code == 2 and needle in output, output
    assert not (tmp_path / "s").exists()


def test_check_on_an_empty_folder_says_so(tmp_path: Path) -> None:
    code, output = invoke("scenarios", "check", str(tmp_path))
    assert code == 2 and "without scenario files" in output, output
