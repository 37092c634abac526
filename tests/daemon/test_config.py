"""The cell config schema: the shipped files load with the paper's numbers; bad files say what is wrong."""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest

from monoguide.daemon.config import load_cell_config
from monoguide.drivers.errors import ConfigError
from monoguide.solver.frames import compose

CONFIG_DIR = Path(__file__).parents[2] / "config"
PAPER_T_CF_W0 = np.array([[-0.9998, -0.0131, -0.0120, -1381.259], [0.0129, -0.9999, 0.0085, -152.268],
                          [-0.0121, 0.0084, 0.9999, 383.642], [0, 0, 0, 1]])

MINIMAL = """
[cell]
name = "test cell"
[camera]
backend = "genicam"
cti = "producer.cti"
serial = "42"
[camera.intrinsics]
width = 640
height = 480
fx = 800.0
fy = 800.0
cx = 320.0
cy = 240.0
[part]
hole_radius_mm = 5.0
points_w = [[0.0, 0.0, 0.0], [100.0, 0.0, 0.0]]
[reference]
T_cf_w0 = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
[[measuring_poses]]
T_cf_si = [[1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, -1.0, 650.0], [0.0, 0.0, 0.0, 1.0]]
[tracker]
backend = "serial"
port = "/dev/ttyUSB0"
baud = 115200
"""


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "cell.toml"
    path.write_text(text)
    return path


def test_sim_cell_holds_the_papers_cell() -> None:
    cfg = load_cell_config(CONFIG_DIR / "sim-cell.toml")
    np.testing.assert_array_equal(cfg.part.points_w[3], [-1.017, 2059.039, -2.677])  # Table 1
    assert (cfg.camera.intrinsics.fx, cfg.camera.intrinsics.k2) == (2421.402, 0.07839)  # Table 2
    np.testing.assert_allclose(cfg.reference.T_cf_w0, PAPER_T_CF_W0, atol=2e-4)
    assert len(cfg.measuring_poses) == 4 and [p.points for p in cfg.measuring_poses] == [(0,), (1,), (2,), (3,)]
    assert cfg.camera.backend == "sim" and cfg.tracker is not None and cfg.tracker.backend == "sim"
    assert cfg.sim is not None and cfg.sim.repeatability_mm == 0.05 and cfg.sim.tracker_noise_mm == 0.025
    assert len(cfg.sim.targets) == 4 and set(cfg.sim.benchmarks) == {"B1", "B2", "B3"}


def test_viky_config_points_at_the_installed_producer() -> None:
    cfg = load_cell_config(CONFIG_DIR / "viky-camera.toml")
    assert cfg.camera.backend == "genicam" and cfg.camera.cti is not None and cfg.camera.cti.is_file()
    assert cfg.camera.region == (0, 0, 640, 480) and cfg.tracker is None


def test_minimal_real_cell_and_relative_paths(tmp_path: Path) -> None:
    cfg = load_cell_config(write(tmp_path, MINIMAL))
    assert cfg.camera.cti == tmp_path / "producer.cti"
    assert cfg.measuring_poses[0].name == "S1" and cfg.measuring_poses[0].points == (0, 1)
    assert cfg.part.point_names == ("P1", "P2") and cfg.tracker is not None and cfg.tracker.baud == 115200


def test_measuring_pose_from_taught_flange_pose_and_mounting(tmp_path: Path) -> None:
    T_b_f = "[[1.0, 0.0, 0.0, 900.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 1000.0], [0.0, 0.0, 0.0, 1.0]]"
    T_f_c = "[[0.0, -1.0, 0.0, 10.0], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 150.0], [0.0, 0.0, 0.0, 1.0]]"
    T_cf_b = "[[1.0, 0.0, 0.0, -500.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]"
    text = (MINIMAL.replace('serial = "42"', f'serial = "42"\nT_f_c = {T_f_c}')
            .replace("[[measuring_poses]]\nT_cf_si",
                     f"[[measuring_poses]]\nT_b_f = {T_b_f}\n[[measuring_poses]]\nT_cf_si")
            .replace("[reference]", f"[reference]\nT_cf_b = {T_cf_b}"))
    cfg = load_cell_config(write(tmp_path, text))
    expected = compose(*(np.array(tomllib.loads(f"m = {m}")["m"]) for m in (T_cf_b, T_b_f, T_f_c)))
    np.testing.assert_allclose(cfg.measuring_poses[0].T_cf_si, expected)
    np.testing.assert_allclose(cfg.measuring_poses[0].T_cf_si[:3, 3], [410.0, 0.0, 1150.0])


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        ('name = "test cell"', "", r"\[cell\]\.name: missing"),
        ('backend = "genicam"', 'backend = "usb"', r"\[camera\]\.backend = 'usb': must be one of"),
        ("fx = 800.0", "fx = -800.0", "focal lengths must be positive"),
        ('cti = "producer.cti"', "", "needs the GenTL producer"),
        ("hole_radius_mm = 5.0", 'hole_radius_mm = "five"', r"hole_radius_mm = 'five': expected a finite number"),
        ("hole_radius_mm = 5.0", "hole_radius_mm = 5.0\nholes = 3", r"unknown key\(s\) \['holes'\]"),
        ("[0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]",
         "[0.0, 2.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]", r"T_cf_w0: rotation part is not"),
        ('port = "/dev/ttyUSB0"', "", "needs the serial port"),
        ("points_w = [[0.0, 0.0, 0.0], [100.0, 0.0, 0.0]]", "points_w = [[0.0, 0.0]]", "points_w = .*expected a list"),
        ("[[measuring_poses]]", "[[measuring_poses]]\npoints = [5]", r"points = \[5\]: \[5\] not among"),
        ('backend = "serial"', 'backend = "sim"', r"needs a \[sim\] section"),
        ("baud = 115200", "baud = 9600.5", r"\[tracker\]\.baud = 9600\.5: expected an integer"),
        ("baud = 115200", "timeout_s = 0", r"\[tracker\]\.timeout_s = 0: must be positive"),
        ('cti = "producer.cti"', "cti = 7", r"\[camera\]\.cti = 7: expected a string"),
    ],
)
def test_bad_files_say_which_key_which_value_why(tmp_path: Path, old: str, new: str, message: str) -> None:
    assert old in MINIMAL
    with pytest.raises(ConfigError, match=message):
        load_cell_config(write(tmp_path, MINIMAL.replace(old, new, 1)))


def test_missing_and_broken_files(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="no such config file"):
        load_cell_config(tmp_path / "absent.toml")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_cell_config(write(tmp_path, "[cell\nname = 1"))


def test_sections_of_later_issues_are_kept_not_fatal(tmp_path: Path) -> None:
    cfg = load_cell_config(write(tmp_path, MINIMAL + '\n[plc]\nhost = "10.0.0.5"\n'))
    assert cfg.extra_sections == {"plc": {"host": "10.0.0.5"}}
