"""``monoguide simulate --calibration CELL.toml`` refuses what ``monoguide run`` on that file refuses: a part type
the wizard has not calibrated (the hood, after the cell and the roof were calibrated) is PART_NOT_CALIBRATED (604)
before the robot moves — the service's config carries the file's ``[calibration]`` provenance with its values.
The calibration is written as the wizard writes it (``write_calibration``, seeded values near the truth); the
simulated part supply's truth log says whether the robot was ever sent to a measuring pose (a part arrives at the
first one). Loopback 127.0.57.x."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np

from monoguide.daemon.calibrate import write_calibration
from monoguide.daemon.config import load_cell_config
from monoguide.daemon.service import Journal
from monoguide.daemon.simulate import derive_config, dumps_toml, read_truth_log
from monoguide.solver.frames import make_T, rotvec_to_matrix

ROOT = Path(__file__).parents[3]
SIM_CELL = ROOT / "config" / "sim-cell.toml"
PROVENANCE = {"session": "/var/lib/monoguide/calibration-session.json", "sim": True, "devices": {"camera": "SIM-1"}}
HOOD_GAP = "never calibrated: steps part, sfi missing"


def test_the_service_config_carries_which_part_types_the_wizard_calibrated(tmp_path: Path) -> None:
    calibrated = _roof_calibrated(tmp_path)
    cell = derive_config(SIM_CELL, tmp_path / "run", host="127.0.57.1", calibration=calibrated)
    service = load_cell_config(cell.service)
    assert (service.calibration_gap(1), service.calibration_gap(2)) == (None, HOOD_GAP)
    assert service.calibration == load_cell_config(calibrated).calibration
    assert cell.calibration is not None and "calibration" in cell.calibration["values"]
    assert load_cell_config(cell.config).calibration is None  # the simulated cell: the truth, as given
    # values entered by hand (no [calibration]) refuse nothing, even where the truth's own file had a provenance
    data = tomllib.loads(calibrated.read_text())
    del data["calibration"]
    by_hand = tmp_path / "by-hand.toml"
    by_hand.write_text(dumps_toml(data))
    again = derive_config(calibrated, tmp_path / "again", host="127.0.57.1", calibration=by_hand)
    believed = load_cell_config(again.service)
    assert believed.calibration is None and believed.calibration_gap(2) is None
    assert "calibration" not in again.calibration["values"]  # type: ignore[index]


def test_simulate_refuses_an_uncalibrated_part_type_before_the_robot_moves(tmp_path: Path) -> None:
    calibrated = _roof_calibrated(tmp_path)
    work = tmp_path / "work"
    done = subprocess.run([sys.executable, "-m", "monoguide.daemon.cli", "simulate", "--work-dir", str(work),
                           "--calibration", str(calibrated), "--jobs", "2", "--cycles", "1", "--json", "--host",
                           "127.0.57.2"], capture_output=True, text=True, timeout=300, cwd=ROOT,
                          env={**os.environ, "COLUMNS": "200"})
    *cycles, summary = [json.loads(line) for line in done.stdout.splitlines()]
    assert [(c["job"], c["error_code"], c["plc_code"]) for c in cycles] == [(2, "PART_NOT_CALIBRATED", 604)], \
        done.stderr[-3000:]
    assert summary["errors"] == {"PART_NOT_CALIBRATED": 1} and summary["offsets_written_on_failure"] == 0
    assert read_truth_log(work / "truth.jsonl") == []  # no part arrived: the robot was never sent to S5
    with Journal(work / "state", read_only=True) as journal:
        (row,) = journal.last_cycles(1)
    assert row.error_message == (f"job 2 (hood): not calibrated in {work / 'service.toml'}: {HOOD_GAP}; nothing "
                                 f"moved (monoguide calibrate --job 2 --config {work / 'service.toml'})")


def _roof_calibrated(tmp_path: Path) -> Path:
    """config/sim-cell.toml after the wizard's cell session (the cell-wide steps and the roof, job 1), its values
    a little off the truth (seeded) as measured ones are; the hood (job 2) not calibrated."""
    path = tmp_path / "calibrated.toml"
    path.write_text(SIM_CELL.read_text())
    cfg = load_cell_config(path)
    rng = np.random.default_rng(3)

    def measured(T: np.ndarray) -> list[list[float]]:
        noise = make_T(rotvec_to_matrix(np.radians(rng.normal(0.0, 0.02, 3))), rng.normal(0.0, 0.2, 3))
        return (np.asarray(T) @ noise).tolist()

    roof = cfg.for_job(1)
    assert cfg.sim is not None
    steps = {
        "intrinsics": {"camera": cfg.camera.intrinsics.as_dict(), "rms_px": 0.1, "images": 8,
                       "done": "2026-11-30T08:00:00+00:00"},
        "cell": {"method": "best-fit", "T_cf_tracker": np.eye(4).tolist(), "rms_mm": 0.01,
                 "done": "2026-11-30T08:05:00+00:00"},
        "base": {"T_cf_b": measured(cfg.reference.T_cf_b), "rms_mm": 0.03, "done": "2026-11-30T08:10:00+00:00"},
        "part": {"T_cf_w0": measured(roof.reference.T_cf_w0), "rms_mm": 0.01, "job": 1,
                 "done": "2026-11-30T08:15:00+00:00"},
        "sfi": {"T_f_c": measured(cfg.sim.T_f_c), "done": "2026-11-30T08:20:00+00:00",
                "poses": [{"name": p.name, "T_cf_si": measured(p.T_cf_si), "visits": 4} for p in roof.measuring_poses]},
    }
    write_calibration(path, steps, PROVENANCE)
    assert load_cell_config(path).calibration_gap(2) == HOOD_GAP
    return path
