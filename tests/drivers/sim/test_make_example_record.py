"""``examples/example-record.json``: reproducible from a clone, and the cell of ``config/sim-cell.toml``.

The cell is checked against the config file read here with tomllib and the pixels against OpenCV's
projection of the record's truth, not through the generator's own chain.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tomllib
from pathlib import Path

import cv2
import numpy as np
import pytest

from monoguide.drivers.sim.make_example_record import main

ROOT = Path(__file__).parents[3]
EXAMPLE_PATH = ROOT / "examples" / "example-record.json"
CONFIG_PATH = ROOT / "config" / "sim-cell.toml"
STALE = ("examples/example-record.json is stale (or config/sim-cell.toml changed): run "
         "python -m monoguide.drivers.sim.make_example_record examples/example-record.json")


def test_the_shipped_example_is_what_the_generator_writes(tmp_path: Path) -> None:
    out = tmp_path / "example.json"
    assert main([str(out), "--config", str(CONFIG_PATH)]) == 0
    assert out.read_text() == EXAMPLE_PATH.read_text(), STALE


def test_the_documented_command_writes_it_from_the_repository_root() -> None:
    run = subprocess.run([sys.executable, "-m", "monoguide.drivers.sim.make_example_record"], cwd=ROOT,
                         capture_output=True, text=True, timeout=60, check=False)
    assert run.returncode == 0, run.stderr
    assert run.stdout == EXAMPLE_PATH.read_text(), STALE


def test_the_example_is_the_cell_of_the_config_file() -> None:
    """The record is job 1's (the roof's) of the config's [[parts]]: its poses by its views, its reference."""
    config = tomllib.loads(CONFIG_PATH.read_text())
    roof = config["parts"][0]
    assert roof["job"] == 1
    example = json.loads(EXAMPLE_PATH.read_text())
    poses = [p for p in config["measuring_poses"] if p["name"] in roof["measuring_poses"]]
    T_cf_si = [np.array(p["T_cf_si"]) for p in poses]
    T_s1_cf = np.linalg.inv(T_cf_si[0])
    for view, T in zip(example["views"], T_cf_si, strict=True):
        np.testing.assert_allclose(view["T_s1_si"], T_s1_cf @ T, atol=1e-6)
    np.testing.assert_allclose(example["T_s1_w0"], T_s1_cf @ np.array(roof["T_cf_w0"]), atol=1e-6)
    T_b_s1 = np.linalg.inv(np.array(config["reference"]["T_cf_b"])) @ T_cf_si[0]
    np.testing.assert_allclose(example["T_b_s1"], T_b_s1, atol=1e-6)
    assert example["camera"] == config["camera"]["intrinsics"]
    np.testing.assert_allclose(example["points_w"], roof["points_w"], atol=5e-4)
    seen = [(o["view"], o["point"]) for o in example["observations"]]
    names = roof["point_names"]
    assert seen == [(i, names.index(h)) for i, pose in enumerate(poses) for h in roof["measuring_poses"][pose["name"]]]


def test_its_pixels_are_the_truth_seen_through_the_camera_with_its_noise() -> None:
    example = json.loads(EXAMPLE_PATH.read_text())
    c = example["camera"]
    K = np.array([[c["fx"], 0.0, c["cx"]], [0.0, c["fy"], c["cy"]], [0.0, 0.0, 1.0]])
    dist = np.array([c["k1"], c["k2"], c["p1"], c["p2"]])
    T_true = np.array(example["truth"]["T_s1_w"])
    errors = []
    for obs in example["observations"]:
        T_si_w = np.linalg.inv(np.array(example["views"][obs["view"]]["T_s1_si"])) @ T_true
        point_si = T_si_w[:3, :3] @ np.array(example["points_w"][obs["point"]]) + T_si_w[:3, 3]
        pixel, _ = cv2.projectPoints(point_si[None], np.zeros(3), np.zeros(3), K, dist)
        errors.append(np.array(obs["pixel"]) - pixel.ravel())
    errors = np.array(errors)
    # 0.1 px noise: no component beyond 4 sigma, and not exact either (the noise is there)
    assert np.max(np.abs(errors)) < 0.4 and np.max(np.abs(errors)) > 0.01
    assert example["sigma_px"] == 0.1


def test_a_config_without_the_reference_is_one_error_line(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    text = CONFIG_PATH.read_text()
    start = text.index("[reference]")
    broken = tmp_path / "cell.toml"
    broken.write_text(text[:start] + text[text.index("\n[", start + 1):])
    assert main([str(tmp_path / "out.json"), "--config", str(broken)]) == 1
    assert "missing key 'reference" in capsys.readouterr().err  # [reference] T_cf_b: the robot base
    assert not (tmp_path / "out.json").exists()
