"""``daemon/calibration_file.py``: the wizard's values written into a copy of a cell config, in place.

Seeded perturbations of the committed configs' values are the ground truth: the rewritten file must load them
back (to 1e-9), keep every other line, comment and the simulated truth, keep the previous file and name it, and
refuse (changing nothing) what would not load.
"""

from __future__ import annotations

import re
import shutil
import tomllib
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from monoguide.daemon.calibrate_session import open_session
from monoguide.daemon.calibration_file import (
    CalibrationFileRefused,
    CalibrationValueInvalid,
    read_calibration_provenance,
    write_calibration,
)
from monoguide.daemon.cmd_calibrate import write_results
from monoguide.daemon.config import load_cell_config
from monoguide.solver.frames import make_T, rotvec_to_matrix

CONFIG_DIR = Path(__file__).parents[2] / "config"
INTRINSICS = ("width", "height", "fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2")
PROVENANCE = {"session": "/var/lib/monoguide/calibration-session.json", "sim": True,
              "devices": {"camera": "sim camera SIM-1", "tracker": "sim tracker LT-1", "robot": "sim-ur UR-1"}}


def _perturbed(T: np.ndarray, rng: np.random.Generator, mm: float = 3.0, deg: float = 0.3) -> np.ndarray:
    """T moved by a seeded rigid perturbation (exactly orthonormal, as a calibration step returns it)."""
    return T @ make_T(rotvec_to_matrix(np.radians(rng.normal(0.0, deg, 3))), rng.normal(0.0, mm, 3))


def _steps(path: Path, seed: int) -> dict[str, dict[str, Any]]:
    """Results of intrinsics, base, part and sfi (docs/calibration.md), seeded, for the config at ``path``."""
    config, rng = load_cell_config(path), np.random.default_rng(seed)
    camera = config.camera.intrinsics.as_dict() | {"fx": 2400.0 + rng.uniform(0, 50), "fy": 2400.0 + rng.uniform(0, 50),
                                                  "cx": 1228.0 + rng.normal(0, 9), "k1": float(rng.normal(0, 0.02))}
    T_f_c = config.camera.T_f_c if config.camera.T_f_c is not None else np.eye(4)
    return {
        "intrinsics": {"camera": camera, "rms_px": 0.14, "per_image_rms_px": [0.1, 0.2], "rejected": {"3": "blurred"},
                       "images": 12, "done": "2025-06-01T10:00:00+00:00"},
        "cell": {"method": "best-fit", "T_cf_tracker": np.eye(4).tolist(), "residuals_mm": {"B1": 0.01, "B2": 0.03},
                 "rms_mm": 0.02, "truth_error": {"cell_mm": 0.011, "cell_deg": 0.001}},
        "base": {"T_cf_b": _perturbed(config.reference.T_cf_b, rng).tolist(), "smr_f": [0, 0, 250],
                 "residuals_mm": [0.01, 0.05, 0.02], "rms_mm": 0.03, "sigma_mm": 0.01, "sigma_deg": 0.0004,
                 "flange_poses": []},
        "part": {"T_cf_w0": _perturbed(config.reference.T_cf_w0, rng).tolist(), "residuals_mm": {"P1": 0.02},
                 "rms_mm": 0.02},
        "sfi": {"poses": [{"name": p.name, "T_cf_si": _perturbed(p.T_cf_si, rng).tolist(), "spread_mm": 0.1 + i,
                           "spread_deg": 0.01, "sem_mm": 0.02, "sem_deg": 0.002, "visits": 4,
                           "deviations_mm": [0.1] * 4} for i, p in enumerate(config.measuring_poses)],
                "T_f_c": _perturbed(T_f_c, rng, 2.0, 0.2).tolist(), "T_f_c_spread_mm": 0.1, "T_f_c_spread_deg": 0.01},
    }


def _copy(tmp_path: Path, name: str) -> Path:
    target = tmp_path / "cell.toml"
    shutil.copyfile(CONFIG_DIR / name, target)
    return target


def _assert_loads(path: Path, steps: dict[str, dict[str, Any]]) -> None:
    config = load_cell_config(path)
    for key in INTRINSICS:
        assert getattr(config.camera.intrinsics, key) == steps["intrinsics"]["camera"][key], key
    np.testing.assert_allclose(config.camera.T_f_c, steps["sfi"]["T_f_c"], rtol=0, atol=1e-9)
    np.testing.assert_allclose(config.reference.T_cf_b, steps["base"]["T_cf_b"], rtol=0, atol=1e-9)
    np.testing.assert_allclose(config.reference.T_cf_w0, steps["part"]["T_cf_w0"], rtol=0, atol=1e-9)
    for pose, expected in zip(config.measuring_poses, steps["sfi"]["poses"], strict=True):
        np.testing.assert_allclose(pose.T_cf_si, expected["T_cf_si"], rtol=0, atol=1e-9)


def _without_calibrated_values(text: str) -> str:
    """The text with the calibrated keys' values blanked (matrices of 4 rows, intrinsics) and [calibration] cut."""
    text = text.split("\n[calibration]")[0]
    text = re.sub(r"^(T_f_c|T_cf_b|T_cf_w0|T_cf_si) = \[([^\n]*)\n(    \[[^\n]*\],\n){4}\]", r"\1 = [\2 ...]", text,
                  flags=re.M)
    return re.sub(rf"^({'|'.join(INTRINSICS)}) = [^\n#]*", r"\1 = ...", text, flags=re.M)


def test_a_round_trip_loads_what_was_written_and_keeps_every_other_line(tmp_path: Path) -> None:
    path = _copy(tmp_path, "sim-cell.toml")
    before = path.read_text()
    truth = load_cell_config(path).sim
    steps = _steps(path, seed=12)
    assert write_calibration(path, steps, PROVENANCE) == path
    _assert_loads(path, steps)
    after = path.read_text()
    assert _without_calibrated_values(after) == _without_calibrated_values(before)
    assert after.count("\n") - before.count("\n") == len(after.split("\n[calibration]")[1].splitlines()) + 1
    sim = load_cell_config(path).sim  # the simulated truth is not a calibrated value
    np.testing.assert_array_equal(sim.T_f_c, truth.T_f_c)
    assert [t.T_cf_t.tolist() for t in sim.targets] == [t.T_cf_t.tolist() for t in truth.targets]

    previous = [p for p in tmp_path.iterdir() if p.name != "cell.toml"]
    assert len(previous) == 1 and re.fullmatch(r"cell\.\d{8}T\d{6}Z\.previous\.toml", previous[0].name)
    assert previous[0].read_text() == before
    provenance = read_calibration_provenance(path)
    assert provenance is not None and provenance["previous"] == previous[0].name
    assert provenance["session"] == PROVENANCE["session"] and provenance["devices"] == PROVENANCE["devices"]
    assert provenance["sim"] is True and provenance["date"].startswith("20")
    assert provenance["steps"]["base"]["max_mm"] == 0.05 and provenance["steps"]["base"]["poses"] == 3
    assert provenance["steps"]["sfi"]["spread_mm_max"] == pytest.approx(3.1)
    assert provenance["steps"]["cell"]["truth_cell_mm"] == 0.011
    assert provenance["steps"]["intrinsics"] == {"done": "2025-06-01T10:00:00+00:00", "rms_px": 0.14, "images": 12,
                                                 "rejected": 1}


def test_the_template_gets_t_cf_si_for_poses_taught_as_flange_poses(tmp_path: Path) -> None:
    """The template's S1, S3, S4 give T_b_f only: T_cf_si is added to them; its comments stay; its
    [calibration] is replaced, keeping the summaries of the steps not written."""
    path = _copy(tmp_path, "cell-template.toml")
    before = path.read_text()
    steps = _steps(path, seed=5)
    write_calibration(path, steps, PROVENANCE)
    _assert_loads(path, steps)
    after = path.read_text()
    comments = [line for line in before.split("\n[calibration]")[0].splitlines() if line.lstrip().startswith("#")]
    assert [line for line in after.splitlines() if line in comments] == comments
    assert after.count("T_b_f = [  # REPLACE") == before.count("T_b_f = [  # REPLACE") == 2
    assert after.count("T_cf_si = [") == 4
    provenance = read_calibration_provenance(path)
    assert provenance["steps"]["accuracy"]["rms_dT_mm"] == 0.3  # kept from the template's [calibration]
    assert provenance["steps"]["sfi"]["poses"] == 4 and "camera" in provenance["devices"]


def test_a_file_that_would_not_load_is_refused_and_nothing_is_lost(tmp_path: Path) -> None:
    path = _copy(tmp_path, "sim-cell.toml")
    path.write_text(path.read_text().replace("grab_timeout_s = 2.0", "grab_timeout_s = 2.0\nexposur_us = 5.0"))
    broken = path.read_bytes()
    steps = _steps(CONFIG_DIR / "sim-cell.toml", seed=3)
    with pytest.raises(CalibrationFileRefused, match=r"exposur_us.*did you mean 'exposure_us'") as raised:
        write_calibration(path, steps, PROVENANCE)
    assert raised.value.plc_code == 726 and str(path) in str(raised.value)
    assert path.read_bytes() == broken and [p.name for p in tmp_path.iterdir()] == ["cell.toml"]

    path.write_text((CONFIG_DIR / "sim-cell.toml").read_text())
    good = path.read_bytes()
    bad = dict(steps, base=dict(steps["base"], T_cf_b=(2.0 * np.eye(4)).tolist()))
    with pytest.raises(CalibrationValueInvalid, match="T_cf_b"):
        write_calibration(path, bad, PROVENANCE)
    unknown = dict(steps, sfi=dict(steps["sfi"], poses=[dict(steps["sfi"]["poses"][0], name="S9")]))
    with pytest.raises(CalibrationValueInvalid, match="S9"):
        write_calibration(path, unknown, PROVENANCE)
    with pytest.raises(CalibrationValueInvalid, match="operator"):
        write_calibration(path, steps, PROVENANCE | {"operator": "me"})
    assert path.read_bytes() == good and [p.name for p in tmp_path.iterdir()] == ["cell.toml"]


def test_two_writes_keep_two_previous_files_and_untouched_steps(tmp_path: Path) -> None:
    path = _copy(tmp_path, "sim-cell.toml")
    original = path.read_text()
    first, second = _steps(path, seed=1), _steps(path, seed=2)
    write_calibration(path, first, PROVENANCE)
    after_first = path.read_text()
    write_calibration(path, {"base": second["base"]}, PROVENANCE | {"sim": False})  # only the base again

    previous = sorted(p for p in tmp_path.iterdir() if p.name != "cell.toml")
    assert len(previous) == 2
    assert {p.read_text() for p in previous} == {original, after_first}
    provenance = read_calibration_provenance(path)
    assert provenance["previous"] != tomllib.loads(after_first)["calibration"]["previous"]
    assert (tmp_path / provenance["previous"]).read_text() == after_first
    assert provenance["sim"] is False and set(provenance["steps"]) == {"intrinsics", "cell", "base", "part", "sfi"}
    expected = dict(first, base=second["base"])  # the other steps' values are those of the first write
    _assert_loads(path, expected)
    assert path.read_text().count("[calibration]") == 1


def test_a_failed_accuracy_validation_keeps_the_calibration_out_unless_accepted(tmp_path: Path) -> None:
    """`monoguide calibrate` after the last step: a FAILED Table-3 verdict writes the report but not the cell
    config (nothing changes, no previous copy); `--accept` writes it."""
    config = _copy(tmp_path, "sim-cell.toml")
    before = config.read_text()
    session, _ = open_session(tmp_path / "work", config, False, {})
    steps = _steps(config, 5)
    row = {"lt": [0.1, 0.2, 0.3, 10.0, 20.0, 30.0], "mono": [0.1, 0.2, 0.3, 10.0, 20.0, 30.9],
           "delta": [0.0, 0.0, 0.0, 0.0, 0.0, 0.9], "dR_deg": 0.0, "dT_mm": 0.9, "dT_grasp_mm": 0.9}
    steps["accuracy"] = {"rows": [row], "rms_dR_deg": 0.0, "rms_dT_mm": 0.9, "rms_dT_grasp_mm": 0.9, "passed": False,
                         "tolerance_mm": 0.5, "tolerance_deg": 0.05, "markdown": "| LT | ... |"}
    for name, result in steps.items():
        session.record_result(name, result)
    assert write_results(session, config, tmp_path / "work", False) is False
    assert config.read_text() == before and not list(tmp_path.glob("*.previous.toml"))
    assert "calibration_file" not in session.data and (tmp_path / "work" / "calibration-report.md").exists()
    assert write_results(session, config, tmp_path / "work", False, accept=True) is True
    _assert_loads(config, steps)
    assert len(list(tmp_path.glob("*.previous.toml"))) == 1
