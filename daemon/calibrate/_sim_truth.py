"""``monoguide calibrate --sim``: how far each step's result is from the simulated cell's truth (docs/calibration.md,
"--sim"; mm and deg from :func:`monoguide.solver.frames.pose_difference`)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from monoguide.daemon.config import CellConfig
from monoguide.solver.frames import compose, invert, pose_difference, transform_points


def truth_error_function(truth: CellConfig) -> Callable[..., dict[str, float]]:
    """``truth_errors(step, result, earlier)``: how far each step's result is from the simulated truth.

    The frames measured with the tracker (base, part, SFi, ``T_s1_w0``) are compared in the cell frame as the
    ``cell`` step of ``earlier`` calibrated it: an error of the cell frame itself moves all of them alike and
    cancels in the offset (only ``T_b_s1``, ``T_s1_si`` and ``T_s1_w0`` reach it), so it is reported once, as
    ``cell_mm`` / ``cell_deg``, and the same figures in the true cell frame as ``*_true_cf``; so are the reference
    marks' centres (``marks_mm_max``, ``marks_mm_rms``: the tracker's noise alone)."""
    sim = truth.sim
    assert sim is not None and truth.reference.T_cf_b is not None
    T_cf_b, T_cf_w0, cam = truth.reference.T_cf_b, truth.reference.T_cf_w0, truth.camera.intrinsics
    T_cf_si = {p.name: p.T_cf_si for p in truth.measuring_poses}
    marks_cf = {m.name: np.asarray(m.position_cf, dtype=float) for m in truth.reference_marks}

    def truth_errors(step: str, result: dict[str, Any], earlier: dict[str, dict[str, Any]] | None = None
                     ) -> dict[str, float]:
        cell = (earlier or {}).get("cell") or {}
        # the true frames in the calibrated cell frame: T_cf'_x = T_cf'_tracker · T_tracker_cf · T_cf_x
        C = (np.asarray(cell["T_cf_tracker"], dtype=float) @ invert(sim.T_cf_tracker)
             if "T_cf_tracker" in cell else np.eye(4))
        out: dict[str, float] = {}

        def frame(name: str, T_est: Any, T_true: np.ndarray) -> None:
            out[f"{name}_deg"], out[f"{name}_mm"] = pose_difference(np.asarray(T_est, dtype=float), C @ T_true)
            if "T_cf_tracker" in cell:
                deg, mm = pose_difference(np.asarray(T_est, dtype=float), T_true)
                out[f"{name}_deg_true_cf"], out[f"{name}_mm_true_cf"] = deg, mm

        if step == "intrinsics" and "camera" in result:
            c = result["camera"]
            out["focal_rel_error"] = max(abs(float(c["fx"]) / cam.fx - 1.0), abs(float(c["fy"]) / cam.fy - 1.0))
        elif step == "cell" and "T_cf_tracker" in result:
            out["cell_deg"], out["cell_mm"] = pose_difference(np.asarray(result["T_cf_tracker"], dtype=float),
                                                              sim.T_cf_tracker)
        elif step == "base":
            if "T_cf_b" in result:
                frame("base", result["T_cf_b"], T_cf_b)
            if "smr_f" in result and sim.tool_smr_f is not None:
                out["smr_mm"] = float(np.linalg.norm(np.asarray(result["smr_f"], dtype=float) - sim.tool_smr_f))
        elif step == "marks":  # each mark's centre against the truth's, in the cell frame as calibrated
            got = {m["name"]: m["position_cf"] for m in result.get("marks", []) if m.get("name") in marks_cf}
            if got:
                measured = np.array([got[n] for n in got], dtype=float).reshape(-1, 3)
                true_cf = np.array([marks_cf[n] for n in got]).reshape(-1, 3)
                errors = np.linalg.norm(measured - transform_points(C, true_cf), axis=1)
                out["marks_mm_max"], out["marks_mm_rms"] = float(errors.max()), float(np.sqrt(np.mean(errors ** 2)))
                if "T_cf_tracker" in cell:
                    out["marks_mm_max_true_cf"] = float(np.linalg.norm(measured - true_cf, axis=1).max())
        elif step == "part" and "T_cf_w0" in result:
            frame("part", result["T_cf_w0"], T_cf_w0)
        elif step == "sfi":
            errors = [(pose_difference(np.asarray(p["T_cf_si"], dtype=float), C @ T_cf_si[p["name"]]),
                       pose_difference(np.asarray(p["T_cf_si"], dtype=float), T_cf_si[p["name"]]))
                      for p in result.get("poses", []) if p.get("name") in T_cf_si]
            if errors:
                out["sfi_deg_max"] = max(e[0][0] for e in errors)
                out["sfi_mm_max"] = max(e[0][1] for e in errors)
                if "T_cf_tracker" in cell:
                    out["sfi_deg_max_true_cf"] = max(e[1][0] for e in errors)
                    out["sfi_mm_max_true_cf"] = max(e[1][1] for e in errors)
            if "T_f_c" in result:  # the camera on the flange: no cell frame in it
                out["hand_eye_deg"], out["hand_eye_mm"] = pose_difference(np.asarray(result["T_f_c"], dtype=float),
                                                                           sim.T_f_c)
        elif step == "verify" and truth.measuring_poses and "T_s1_w0" in result:  # relative: no cell frame in it
            T_s1_w0 = compose(invert(truth.measuring_poses[0].T_cf_si), T_cf_w0)
            out["s1_w0_deg"], out["s1_w0_mm"] = pose_difference(np.asarray(result["T_s1_w0"], dtype=float), T_s1_w0)
        return out

    return truth_errors
