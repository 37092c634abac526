"""The cell config schema: the shipped files load with the paper's numbers; bad files say what is wrong."""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest

from monoguide.daemon.config import load_cell_config
from monoguide.daemon.errors import ConfigMissingKey, ConfigUnknownKey, ConfigUnknownSection
from monoguide.drivers.errors import ConfigError
from monoguide.solver.frames import compose

CONFIG_DIR = Path(__file__).parents[3] / "config"
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
k1 = -0.02
k2 = 0.07
p1 = 0.001
p2 = 0.0007
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
    assert len(cfg.sim.targets) == len(cfg.cell_poses) == 7 and set(cfg.sim.benchmarks) == {"B1", "B2", "B3"}


@pytest.mark.parametrize("path", sorted(CONFIG_DIR.glob("*.toml")), ids=lambda p: p.name)
def test_every_shipped_config_loads(path: Path) -> None:
    cfg = load_cell_config(path)
    assert cfg.path == path and cfg.measuring_poses


def test_viky_config_points_at_the_installed_producer() -> None:
    cfg = load_cell_config(CONFIG_DIR / "viky-camera.toml")
    assert cfg.camera.backend == "genicam" and cfg.camera.cti is not None and cfg.camera.cti.is_file()
    assert cfg.camera.region == (0, 0, 640, 480) and cfg.tracker is None


def test_minimal_real_cell_and_relative_paths(tmp_path: Path) -> None:
    cfg = load_cell_config(write(tmp_path, MINIMAL))
    assert cfg.camera.cti == tmp_path / "producer.cti"
    assert cfg.measuring_poses[0].name == "S1" and cfg.measuring_poses[0].points == (0, 1)
    assert cfg.part.point_names == ("P1", "P2") and cfg.tracker is not None and cfg.tracker.baud == 115200
    intr = cfg.camera.intrinsics
    assert (intr.k1, intr.k2, intr.p1, intr.p2) == (-0.02, 0.07, 0.001, 0.0007)


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
        ("[0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]",
         "[0.0, 2.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]", r"T_cf_w0: rotation part is not"),
        ('port = "/dev/ttyUSB0"', "", "needs the serial port"),
        ("points_w = [[0.0, 0.0, 0.0], [100.0, 0.0, 0.0]]", "points_w = [[0.0, 0.0]]", "points_w = .*expected a list"),
        ("[[measuring_poses]]", "[[measuring_poses]]\npoints = [5]", r"points = \[5\]: \[5\] not among"),
        ('backend = "serial"', 'backend = "sim"', r"needs a \[sim\] section"),
        ("baud = 115200", "baud = 9600.5", r"\[tracker\]\.baud = 9600\.5: expected an integer"),
        ("baud = 115200", "timeout_s = 0", r"\[tracker\]\.timeout_s = 0: must be 0\.05 to 600 s"),
        ('cti = "producer.cti"', "cti = 7", r"\[camera\]\.cti = 7: expected a string"),
        ("width = 640", "width = 640.5", r"\[camera\.intrinsics\]\.width = 640\.5: expected an integer"),
        ("k2 = 0.07", 'k2 = "0.07"', r"\[camera\.intrinsics\]\.k2 = '0\.07': expected a finite number"),
        ('backend = "genicam"', 'backend = "genicm"', r"\[camera\]\.backend = 'genicm'.*did you mean 'genicam'"),
        # non-finite numbers (TOML has nan and inf)
        ("fx = 800.0", "fx = nan", r"\[camera\.intrinsics\]\.fx = nan: expected a finite number"),
        ("hole_radius_mm = 5.0", "hole_radius_mm = inf", r"\[part\]\.hole_radius_mm = inf: expected a finite"),
        ("[0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]\n[[", "[0.0, 0.0, 1.0, -inf], [0.0, 0.0, 0.0, 1.0]]\n[[",
         r"\[reference\]\.T_cf_w0 = .*-inf.*: numbers must be finite"),
        # matrices that are not rigid transforms
        ("[[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]",
         "[[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0]",
         r"\[reference\]\.T_cf_w0: rotation part is not a rotation .*det = -1"),
        ("[0.0, 0.0, -1.0, 650.0], [0.0, 0.0, 0.0, 1.0]]", "[0.0, 0.0, -1.0, 650.0], [0.0, 0.0, 1.0, 1.0]]",
         r"\[\[measuring_poses\]\] #1\.T_cf_si: last row must be \[0, 0, 0, 1\]"),
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


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        ("k1 = -0.02\n", "", r"\[camera\.intrinsics\]\.k1: missing"),  # never a zero
        ("p2 = 0.0007\n", "", r"\[camera\.intrinsics\]\.p2: missing"),
        ("cy = 240.0\n", "", r"\[camera\.intrinsics\]\.cy: missing"),
        ("hole_radius_mm = 5.0\n", "", r"\[part\]\.hole_radius_mm: missing"),
        ("[reference]\nT_cf_w0", "[reference]\nT_cf_w", r"\[reference\]\.T_cf_w0: missing"),
        ("[camera.intrinsics]\n", "[camera.intrinsic]\n", r"\[camera\.intrinsics\]: missing.*'intrinsic' is there"),
        ("k1 = -0.02", "k_1 = -0.02", r"\[camera\.intrinsics\]\.k1: missing \('k_1' is there: a misspelling\?\)"),
        ("[[measuring_poses]]\nT_cf_si = [[1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, -1.0, 650.0], "
         "[0.0, 0.0, 0.0, 1.0]]\n", "", r"\[measuring_poses\]: missing"),
    ],
)
def test_a_missing_key_is_an_error_naming_it(tmp_path: Path, old: str, new: str, message: str) -> None:
    assert old in MINIMAL
    with pytest.raises(ConfigMissingKey, match=message) as info:
        load_cell_config(write(tmp_path, MINIMAL.replace(old, new, 1)))
    assert (info.value.code, info.value.plc_code) == ("CONFIG_MISSING_KEY", 532)


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        ("p2 = 0.0007", "p2 = 0.0007\nk3 = 0.0", r"\[camera\.intrinsics\]\.k3: unknown key; known keys: \['cx'"),
        ("[part]\n", "[part]\nhole_radius = 5.0\n",
         r"\[part\]\.hole_radius: unknown key; did you mean 'hole_radius_mm'"),
        ('serial = "42"', 'serial = "42"\nexposure_usec = 900.0', r"\[camera\]\.exposure_usec: .*'exposure_us'"),
        ("[[measuring_poses]]\n", "[[measuring_poses]]\npoint = [0]\n",
         r"\[\[measuring_poses\]\] #1\.point: unknown key; did you mean 'points'\?"),
        ("baud = 115200", "baud = 115200\ntimeout_ms = 300",
         r"\[tracker\]\.timeout_ms: unknown key; did you mean 'timeout_s'\?"),
        ("hole_radius_mm = 5.0", "hole_radius_mm = 5.0\nholes = 3", r"\[part\]\.holes: unknown key; known keys: \["),
    ],
)
def test_an_unknown_key_is_an_error_suggesting_the_closest(tmp_path: Path, old: str, new: str, message: str) -> None:
    assert old in MINIMAL
    with pytest.raises(ConfigUnknownKey, match=message) as info:
        load_cell_config(write(tmp_path, MINIMAL.replace(old, new, 1)))
    assert (info.value.code, info.value.plc_code) == ("CONFIG_UNKNOWN_KEY", 530)


def test_unknown_keys_in_the_sim_section_and_its_tables(tmp_path: Path) -> None:
    text = (CONFIG_DIR / "sim-cell.toml").read_text()
    cases = [("[sim.deviation]", "[sim.deviation]\nrotation = [1.0, 1.0, 1.0]",
              r"\[sim\.deviation\]\.rotation: .*'rotation_deg'"),
             ("[sim]\n", "[sim]\nseeds = 3\n", r"\[sim\]\.seeds: unknown key; did you mean 'seed'\?"),
             ('name = "T2"', 'name = "T2"\npoint_t = []', r"\[\[sim\.targets\]\] #2\.point_t: .*'points_t'")]
    for old, new, message in cases:
        assert old in text
        with pytest.raises(ConfigUnknownKey, match=message):
            load_cell_config(write(tmp_path, text.replace(old, new, 1)))


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        ("[tracker]", "[trackr]", r"unknown section \[trackr\]; did you mean \[tracker\]\?"),
        ("[camera]\n", "[camra]\n", r"unknown section \[camra\]; did you mean \[camera\]\?"),  # not "[camera] missing"
        ("[[measuring_poses]]", "[[measuring_pose]]",
         r"unknown section \[measuring_pose\]; did you mean \[measuring_poses\]"),
        ("[cell]", '[conveyor]\nhost = "10.0.0.5"\n[cell]',
         r"unknown section \[conveyor\]; known sections: \[.*'\[tracker\]'"),
    ],
)
def test_an_unknown_section_is_an_error_suggesting_the_closest(tmp_path: Path, old: str, new: str,
                                                                message: str) -> None:
    assert old in MINIMAL
    with pytest.raises(ConfigUnknownSection, match=message) as info:
        load_cell_config(write(tmp_path, MINIMAL.replace(old, new, 1)))
    assert (info.value.code, info.value.plc_code) == ("CONFIG_UNKNOWN_SECTION", 531)


def test_a_key_outside_any_section_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ConfigUnknownKey, match=r"cell\.toml: name = 'x': a key outside any section"):
        load_cell_config(write(tmp_path, 'name = "x"\n' + MINIMAL))


def test_config_errors_are_config_errors_with_their_own_plc_codes() -> None:
    classes = (ConfigUnknownKey, ConfigUnknownSection, ConfigMissingKey)
    assert all(issubclass(c, ConfigError) for c in classes)
    codes = [c.plc_code for c in classes]
    assert len(set(codes)) == len(codes) and all(530 <= c <= 549 for c in codes)
    assert len({c.code for c in classes} | {ConfigError.code}) == len(classes) + 1
