"""The wizard by part type: ``monoguide calibrate --job N`` on a cell of ``[[parts]]``.

The cell's session calibrates the cell-wide steps and the first part type (the roof); ``--job 2`` calibrates the
hood's part, sfi, verify and accuracy in its own session with the cell's intrinsics, frame and base, and writes
the hood's values and ``[calibration.parts.2]`` into the same config. A part type the wizard has not calibrated
(or calibrated before the cell was recalibrated) is named with its missing steps (the cycle refuses its jobs with
PART_NOT_CALIBRATED: tests/daemon/service/test_part_types.py). Seeded values and the simulated truth config are
the ground truth. Loopback 127.0.31.x.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from helpers.cell_configs import cell_config

from monoguide.daemon.calibrate import SESSION_FILE, write_calibration
from monoguide.daemon.config import load_cell_config
from monoguide.drivers.errors import ConfigError
from monoguide.solver.frames import make_T, pose_difference, rotvec_to_matrix

SIM_CELL = Path(__file__).parents[3] / "config" / "sim-cell.toml"
PROVENANCE = {"session": "/var/lib/monoguide/calibration-session.json", "sim": True, "devices": {"camera": "SIM-1"}}
CELL_DONE = {"intrinsics": "2026-11-30T08:00:00+00:00", "cell": "2026-11-30T08:05:00+00:00",
             "base": "2026-11-30T08:10:00+00:00"}
SMALL = ["--plate-images", "8", "--base-poses", "10", "--placements", "2", "--visits", "2", "--repeats", "2",
         "--accuracy-poses", "2"]


def _moved(T: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    return np.asarray(T) @ make_T(rotvec_to_matrix(np.radians(rng.normal(0.0, 0.2, 3))), rng.normal(0.0, 2.0, 3))


def _cell_results(cfg: Any, rng: np.random.Generator) -> dict[str, dict[str, Any]]:
    """Seeded results of the cell's session (every step, the roof's part and poses S1-S4)."""
    roof = cfg.for_job(1)
    return {
        "intrinsics": {"camera": cfg.camera.intrinsics.as_dict(), "rms_px": 0.1, "images": 8,
                       "done": CELL_DONE["intrinsics"]},
        "cell": {"method": "best-fit", "T_cf_tracker": np.eye(4).tolist(), "rms_mm": 0.01, "done": CELL_DONE["cell"]},
        "base": {"T_cf_b": _moved(cfg.reference.T_cf_b, rng).tolist(), "rms_mm": 0.03, "done": CELL_DONE["base"]},
        "part": {"T_cf_w0": _moved(roof.reference.T_cf_w0, rng).tolist(), "rms_mm": 0.01, "job": 1,
                 "done": "2026-11-30T08:15:00+00:00"},
        "sfi": {"T_f_c": _moved(cfg.sim.T_f_c, rng).tolist(), "done": "2026-11-30T08:20:00+00:00",
                "poses": [{"name": p.name, "T_cf_si": _moved(p.T_cf_si, rng).tolist(), "visits": 4}
                          for p in roof.measuring_poses]},
    }


def _hood_results(cfg: Any, rng: np.random.Generator) -> dict[str, dict[str, Any]]:
    hood = cfg.for_job(2)
    return {
        "part": {"T_cf_w0": _moved(hood.reference.T_cf_w0, rng).tolist(), "rms_mm": 0.01, "job": 2,
                 "done": "2026-11-30T09:00:00+00:00"},
        "sfi": {"T_f_c": _moved(cfg.sim.T_f_c, rng).tolist(), "done": "2026-11-30T09:05:00+00:00",
                "poses": [{"name": p.name, "T_cf_si": _moved(p.T_cf_si, rng).tolist(), "visits": 4}
                          for p in hood.measuring_poses]},
    }


def test_each_part_type_keeps_its_values_and_its_provenance(tmp_path: Path) -> None:
    config = tmp_path / "cell.toml"
    config.write_text(SIM_CELL.read_text())
    before = load_cell_config(config)
    assert [before.calibration_gap(job) for job in before.jobs] == [None, None]  # hand-entered: nothing refused
    rng = np.random.default_rng(19)
    cell, hood = _cell_results(before, rng), _hood_results(before, rng)

    write_calibration(config, cell, PROVENANCE)
    after_cell = load_cell_config(config)
    assert after_cell.calibration_gap(1) is None
    assert after_cell.calibration_gap(2) == "never calibrated: steps part, sfi missing"

    write_calibration(config, hood, PROVENANCE, part={"job": 2, "name": "hood", "cell_steps": CELL_DONE})
    both = load_cell_config(config)
    assert [both.calibration_gap(job) for job in both.jobs] == [None, None]
    np.testing.assert_allclose(both.for_job(2).reference.T_cf_w0, hood["part"]["T_cf_w0"], atol=1e-9)
    np.testing.assert_allclose(both.for_job(1).reference.T_cf_w0, cell["part"]["T_cf_w0"], atol=1e-9)
    for pose in hood["sfi"]["poses"] + cell["sfi"]["poses"]:
        (got,) = [p.T_cf_si for p in both.cell_poses if p.name == pose["name"]]
        np.testing.assert_allclose(got, pose["T_cf_si"], atol=1e-9)
    # the camera's mounting is the cell's: the hood's session does not move it
    np.testing.assert_allclose(both.camera.T_f_c, cell["sfi"]["T_f_c"], atol=1e-9)
    entry = both.calibration["parts"][2]
    assert entry["name"] == "hood" and entry["cell_steps"] == CELL_DONE and set(entry["steps"]) == {"part", "sfi"}
    assert set(both.calibration["steps"]) == set(cell)  # the cell's provenance is kept

    # the cell recalibrated (its frame redone): the hood's values were measured in the old frame
    redo = {"cell": {**cell["cell"], "done": "2026-12-01T07:00:00+00:00"}}
    write_calibration(config, redo, PROVENANCE)
    stale = load_cell_config(config)
    assert stale.calibration["parts"][2]["cell_steps"] == CELL_DONE  # kept through the cell's write
    assert stale.calibration_gap(1) is None
    gap = stale.calibration_gap(2)
    assert gap is not None and "cell on 2026-12-01T07:00:00+00:00" in gap and "part, sfi must be redone" in gap


def test_a_part_type_entry_keyed_by_anything_but_a_job_number_is_refused(tmp_path: Path) -> None:
    config = tmp_path / "cell.toml"
    config.write_text(SIM_CELL.read_text() + '\n[calibration]\ndate = "2026-12-01T06:00:00+00:00"\n'
                      '[calibration.parts.hood]\nname = "hood"\n')
    with pytest.raises(ConfigError, match=r"\[calibration.parts\] 'hood': expected a part type's job number"):
        load_cell_config(config)


def _calibrate(work: Path, *args: str) -> subprocess.CompletedProcess[str]:
    """The wizard on the simulated cell, its truth a copy of config/sim-cell.toml whose robot moves in 0.05 s and
    whose lens has no defocus blur (the geometry, the ground truth here, is the same; the time is not)."""
    truth = work.parent / "sim-cell-quick.toml"
    if not truth.exists():
        cell_config(work.parent, "127.0.31.1", sharp=True, name=truth.name)
    return subprocess.run([sys.executable, "-m", "monoguide.daemon.cli", "calibrate", "--sim", "--yes", "--json",
                           "--config", str(truth), "--work-dir", str(work), "--host", "127.0.31.1", "--seed", "4",
                           *args], capture_output=True, text=True, timeout=300)


def test_the_wizard_refuses_a_part_session_without_the_cell_and_cell_steps_by_job(tmp_path: Path) -> None:
    work = tmp_path / "work"
    early = _calibrate(work, "--job", "2")
    assert early.returncode == 2 and "calibrate the cell (and its first part type) without --job first" in early.stderr
    assert not (work / "job-2").exists()
    for args, words in ((["--job", "3"], "no part of job 3; the cell's jobs are"),
                        (["intrinsics", "--job", "2"], "STEP intrinsics: a cell-wide step"),
                        (["--from", "base", "--job", "2"], "--from base: a cell-wide step")):
        run = _calibrate(work, *args)
        assert run.returncode == 2 and words in run.stderr, (args, run.stderr[-2000:])


@pytest.mark.slow
@pytest.mark.timeout(600)  # two wizard sessions, ~100 s on 2 idle cores; each run has its own 300 s limit
def test_the_hood_is_calibrated_in_its_own_session_against_the_truth(tmp_path: Path) -> None:
    work = tmp_path / "work"
    cell = _calibrate(work, *SMALL)
    assert cell.returncode == 0, cell.stderr[-3000:]
    calibrated = work / "cell.toml"
    assert load_cell_config(calibrated).calibration_gap(2) == "never calibrated: steps part, sfi missing"

    hood = _calibrate(work, "--job", "2")  # the cell's session's options (small counts) carry over
    assert hood.returncode == 0, hood.stderr[-3000:]
    summary = json.loads(hood.stdout.strip().splitlines()[-1])
    assert summary["steps_done"] == ["part", "sfi", "verify", "accuracy"] and summary["refused"] == {}
    session = json.loads((work / "job-2" / SESSION_FILE).read_text())
    assert session["job"] == 2 and session["options"]["placements"] == 2
    assert "--- step 'part' of job 2 (hood) (1 of 4)" in hood.stderr

    truth, done = load_cell_config(SIM_CELL), load_cell_config(calibrated)
    assert [done.calibration_gap(job) for job in done.jobs] == [None, None]
    # against the truth config, in the calibrated cell frame (its own error moves every frame alike)
    cell_steps = json.loads((work / SESSION_FILE).read_text())["steps"]
    C = np.array(cell_steps["cell"]["T_cf_tracker"]) @ np.linalg.inv(truth.sim.T_cf_tracker)
    deg, mm = pose_difference(done.for_job(2).reference.T_cf_w0, C @ truth.for_job(2).reference.T_cf_w0)
    assert mm < 0.1 and deg < 0.01, (mm, deg)  # the cell before calibration had it 5 mm / 0.3 deg off
    for pose in done.for_job(2).measuring_poses:
        (true_pose,) = [p for p in truth.cell_poses if p.name == pose.name]
        deg, mm = pose_difference(pose.T_cf_si, C @ true_pose.T_cf_si)
        assert mm < 0.4 and deg < 0.05, (pose.name, mm, deg)
    # the roof's values are the cell session's, untouched by the hood's
    roof_T = np.array(cell_steps["part"]["T_cf_w0"])
    np.testing.assert_allclose(done.for_job(1).reference.T_cf_w0, roof_T, atol=1e-9)
    np.testing.assert_allclose(done.camera.T_f_c, cell_steps["sfi"]["T_f_c"], atol=1e-9)
    assert done.calibration["parts"][2]["cell_steps"] == {s: cell_steps[s]["done"] for s in ("intrinsics", "cell",
                                                                                              "base")}
    assert session["steps"]["accuracy"]["passed"] is True
