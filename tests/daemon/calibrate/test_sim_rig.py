"""``open_sim_rig``: the cell before calibration, the simulated cell as a child that is gone afterwards, the devices
over their real transports, and the truth errors. Loopback 127.0.14.30-39."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from monoguide.daemon.assembly import read_sim_state
from monoguide.daemon.calibrate import CalibrationOptions, open_sim_rig
from monoguide.daemon.config import load_cell_config
from monoguide.daemon.errors import SimRigConfigError
from monoguide.solver.frames import compose, invert, pose_difference, transform_points

SIM_CELL = Path(__file__).parents[3] / "config" / "sim-cell.toml"


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return Path(f"/proc/{pid}/stat").exists() and Path(f"/proc/{pid}/stat").read_text().split()[2] != "Z"


def _our_children() -> list[str]:
    path = Path(f"/proc/{os.getpid()}/task/{os.getpid()}/children")
    return [c for c in path.read_text().split() if _alive(int(c))]


def test_open_sim_rig_opens_a_perturbed_cell_and_leaves_nothing_behind(tmp_path: Path) -> None:
    truth = load_cell_config(SIM_CELL)
    assert truth.sim is not None and truth.reference.T_cf_b is not None
    lines: list[str] = []
    with open_sim_rig(SIM_CELL, tmp_path, CalibrationOptions(base_poses=4), seed=5, host="127.0.14.30",
                      progress=lines.append) as rig:
        state_file = rig.config.sim.state_file  # type: ignore[union-attr]
        state = read_sim_state(state_file)
        pids = [state["pid"], state["tracker"]["pid"], state["robot"]["pid"]]
        assert rig.sim and rig.config_path == tmp_path / "cell.toml"

        # the cell before calibration: its calibration values off the truth by what was asked, the truth left out
        cfg = rig.config
        deg, mm = pose_difference(cfg.reference.T_cf_b, truth.reference.T_cf_b)
        assert deg == pytest.approx(0.3, abs=1e-6) and mm == pytest.approx(5.0, abs=1e-6)
        assert pose_difference(cfg.camera.T_f_c, truth.sim.T_f_c)[1] == pytest.approx(2.0, abs=1e-6)
        assert 0 < abs(cfg.camera.intrinsics.fx / truth.camera.intrinsics.fx - 1) <= 0.015
        assert cfg.camera.intrinsics.k1 == 0.0
        for pose, true_pose in zip(cfg.measuring_poses, truth.measuring_poses, strict=True):
            assert pose_difference(pose.T_cf_si, true_pose.T_cf_si)[1] == pytest.approx(3.0, abs=1e-6)
            taught = compose(invert(truth.reference.T_cf_b), true_pose.T_cf_si, invert(truth.sim.T_f_c))
            assert np.allclose(pose.T_b_f, taught)  # the robot program's taught pose is known
        assert cfg.sim is not None and cfg.sim.tool_smr_f is None and not cfg.sim.benchmarks and not cfg.sim.targets
        assert cfg.cell_frame is not None and set(cfg.cell_frame.benchmarks) == set(truth.sim.benchmarks)
        assert cfg.calibration_target is not None and len(cfg.calibration_target.nests_t) == 4

        # the devices over their transports: a benchmark where the truth has it, the robot at a calibration pose
        rig.operator.ask("place_smr", "place the SMR in B2", nest="B2")
        b2 = transform_points(invert(truth.sim.T_cf_tracker), truth.sim.benchmarks["B2"].reshape(1, 3))[0]
        assert np.linalg.norm(rig.tracker.measure_point(nest="B2").point_mm - b2) < 0.15
        assert rig.robot.move_to_calibration_pose(4).in_position == 104
        assert rig.camera.grab(2.0).image.shape == (truth.camera.intrinsics.height, truth.camera.intrinsics.width)

        # the truth errors: nothing for the truth itself, the perturbation for the cell before calibration
        errors = rig.truth_errors
        assert errors is not None
        perfect = errors("base", {"T_cf_b": truth.reference.T_cf_b.tolist(), "smr_f": truth.sim.tool_smr_f.tolist()})
        assert perfect == pytest.approx({"base_mm": 0.0, "base_deg": 0.0, "smr_mm": 0.0}, abs=1e-9)
        before = errors("sfi", {"poses": [{"name": p.name, "T_cf_si": p.T_cf_si.tolist()} for p in cfg.measuring_poses],
                                "T_f_c": cfg.camera.T_f_c.tolist()})
        assert before["sfi_mm_max"] == pytest.approx(3.0, abs=1e-6)
        assert before["hand_eye_deg"] == pytest.approx(0.2, abs=1e-6)
        intr = errors("intrinsics", {"camera": {"fx": truth.camera.intrinsics.fx * 1.001,
                                                "fy": truth.camera.intrinsics.fy}})
        assert intr["focal_rel_error"] == pytest.approx(0.001)
        assert errors("accuracy", {"rows": []}) == {}
    assert not [pid for pid in pids if _alive(pid)], "a simulated device outlived the rig"
    assert not _our_children()
    assert not Path(state_file).exists()
    assert any("starting the simulated cell" in line for line in lines)


def test_a_cell_without_the_flange_smr_is_refused_before_anything_starts(tmp_path: Path) -> None:
    text = SIM_CELL.read_text()
    assert "tool_smr_f = " in text
    config = tmp_path / "no-smr.toml"
    config.write_text("\n".join(line for line in text.splitlines() if not line.startswith("tool_smr_f")))
    with pytest.raises(SimRigConfigError, match="tool_smr_f"), \
            open_sim_rig(config, tmp_path / "work", CalibrationOptions(), host="127.0.14.31"):
        pass
    assert not _our_children()
    assert not (tmp_path / "work" / "cell.toml").exists()
