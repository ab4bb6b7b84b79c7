"""Sensor sections of scenario files: out-of-range noise parameters are rejected at load, in one line that
names the field's path, with exit code 2 from the CLI; valid sections load with their units' values."""

from __future__ import annotations

import copy
from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from llmnav.cli import app
from llmnav.errors import ScenarioError
from llmnav.world.scenario import DetectorConfig, OdometryConfig, parse_scenario

runner = CliRunner()

TINY: dict = {
    "name": "tiny",
    "robot": "burger",
    "bounds": {"x": [0, 4], "y": [0, 4]},
    "objects": [{"id": "door", "label": "door", "center": [3.5, 3.5], "size": [0.4, 0.1], "solid": False}],
}

# (section, field, bad value, words the problem must contain)
BAD = [
    ("detector", "distance_noise_std_m", -0.1, "greater than or equal to 0"),
    ("detector", "distance_noise_per_m", -0.01, "greater than or equal to 0"),
    ("detector", "bearing_noise_std_deg", -2.0, "greater than or equal to 0"),
    ("detector", "dropout", 1.5, "less than or equal to 1"),
    ("detector", "dropout", -0.1, "greater than or equal to 0"),
    ("detector", "distance_bias", -1.0, "greater than -1"),
    ("detector", "distance_noise_per_m", float("nan"), "finite"),
    ("detector", "distance_noise_std_m", float("inf"), "finite"),
    ("detector", "max_distance_m", float("inf"), "finite"),
    ("detector", "max_distance_m", 0.0, "greater than 0"),
    ("detector", "occlusion", "sometimes", "mask"),
    ("detector", "noise", 0.1, "extra"),
    ("odometry", "wheel_scale_std", -0.01, "greater than or equal to 0"),
    ("odometry", "track_scale_std", float("nan"), "finite"),
    ("odometry", "wheel_noise_m_per_sqrt_m", float("inf"), "finite"),
    ("lidar", "noise_std_m", float("nan"), "finite"),
]
IDS = [f"{section}.{field}={value}" for section, field, value, _ in BAD]


def with_sensor(section: str, field: str, value: object) -> dict:
    data = copy.deepcopy(TINY)
    data["sensors"] = {section: {field: value}}
    return data


@pytest.mark.parametrize(("section", "field", "value", "problem"), BAD, ids=IDS)
def test_out_of_range_is_rejected_with_the_fields_path(section: str, field: str, value: object, problem: str) -> None:
    with pytest.raises(ScenarioError) as err:
        parse_scenario(with_sensor(section, field, value), "tiny.yaml")
    message = str(err.value)
    assert "\n" not in message
    assert message.startswith(f"tiny.yaml: sensors.{section}.{field}: "), message
    assert problem.lower() in message.lower(), message


@pytest.mark.parametrize(
    ("field", "text"),
    [
        ("distance_noise_std_m", "-0.1"),
        ("dropout", "1.5"),
        ("distance_noise_per_m", ".nan"),
        ("bearing_noise_std_deg", ".inf"),
    ],
)
def test_cli_gives_one_line_and_exit_code_2(tmp_path: Path, field: str, text: str) -> None:
    path = tmp_path / "noisy.yaml"
    path.write_text(yaml.safe_dump(TINY) + f"sensors:\n  detector:\n    {field}: {text}\n")
    result = runner.invoke(app, ["scenarios", "show", str(path)])
    assert result.exit_code == 2
    assert result.stdout == ""
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and f"sensors.detector.{field}" in lines[0] and str(path) in lines[0], result.stderr
    assert "Traceback" not in result.output


def test_valid_sections_load() -> None:
    data = copy.deepcopy(TINY)
    data["sensors"] = {
        "detector": {"distance_noise_per_m": 0.15, "bearing_noise_std_deg": 2, "dropout": 0.05, "occlusion": "center"},
        "odometry": {"wheel_scale_std": 0, "track_scale_std": 0, "wheel_noise_m_per_sqrt_m": 0},
    }
    sensors = parse_scenario(data, "tiny.yaml").sensors
    assert sensors.detector.distance_sigma(2.0) == pytest.approx(0.30)
    assert sensors.detector.occlusion == "center" and not sensors.detector.ideal
    assert sensors.odometry.is_exact and sensors.odometry == OdometryConfig.exact()
    # Without a section: an ideal detector and exact odometry (bundled worlds set their own).
    plain = parse_scenario(copy.deepcopy(TINY), "tiny.yaml").sensors
    assert plain.detector == DetectorConfig() and plain.detector.ideal
    assert plain.odometry.is_exact and not OdometryConfig.typical().is_exact
