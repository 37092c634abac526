"""What the wizard says about its results: each step's residual summary (``[calibration.steps]`` of the calibrated
config, the report's table), a short human summary of each step's result, and the ``--json`` summary of a
session (docs/calibration.md, "--json")."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from monoguide.daemon.calibrate._session import CalibrationSession

SUMMARY_KEYS = ("base_mm", "base_deg", "sfi_mm_max", "sfi_deg_max", "focal_rel_error")


def summary(session: CalibrationSession) -> dict[str, Any]:
    """The ``--json`` summary: every truth error of the steps done (``None`` where unknown: on a real cell),
    the steps done, the refusals, and where the calibration and the report went."""
    out: dict[str, Any] = dict.fromkeys(SUMMARY_KEYS)
    for result in session.results().values():
        out.update(result.get("truth_error") or {})
    out.update({"calibration_file": session.data.get("calibration_file"), "report": session.data.get("report"),
                "session": str(session.path), "sim": bool(session.data.get("sim")), "steps_done": session.done(),
                "refused": session.data.get("refused", {})})
    return out


def step_summary(step: str, result: dict[str, Any]) -> dict[str, Any]:
    """The residual summary of one step's result written to ``[calibration.steps]`` (numbers, strings, booleans,
    lists of numbers; non-finite numbers left out). In --sim the step's ``truth_error`` keys as ``truth_<key>``."""
    r = result
    out: dict[str, Any] = {}
    if isinstance(r.get("done"), str):
        out["done"] = r["done"]
    if step == "intrinsics":
        out |= {"rms_px": r.get("rms_px"), "images": r.get("images"), "rejected": len(r.get("rejected") or {})}
    elif step in ("cell", "part"):
        res = list((r.get("residuals_mm") or {}).values())
        out |= {"method": r.get("method"), "rms_mm": r.get("rms_mm"), "max_mm": max(res) if res else None}
    elif step == "marks":
        out |= {"marks": len(r.get("marks") or []), "max_deviation_mm": r.get("max_deviation_mm"),
                "max_deviation_mark": r.get("max_deviation_mark"), "rms_deviation_mm": r.get("rms_deviation_mm"),
                "tolerance_mm": r.get("tolerance_mm"), "max_tracker_rms_mm": r.get("max_tracker_rms_mm")}
    elif step == "base":
        res = list(r.get("residuals_mm") or [])
        out |= {"rms_mm": r.get("rms_mm"), "max_mm": max(res) if res else None, "poses": len(res),
                "sigma_mm": r.get("sigma_mm"), "sigma_deg": r.get("sigma_deg")}
    elif step == "sfi":
        poses = r.get("poses") or []
        out |= {"spread_mm_max": max((p.get("spread_mm", 0.0) for p in poses), default=None),
                "spread_deg_max": max((p.get("spread_deg", 0.0) for p in poses), default=None),
                "visits": sum(int(p.get("visits", 0)) for p in poses), "poses": len(poses),
                "hand_eye_spread_mm": r.get("T_f_c_spread_mm"), "hand_eye_spread_deg": r.get("T_f_c_spread_deg")}
    elif step == "verify":
        out |= {k: r.get(k) for k in ("max_mm", "max_deg", "n", "sigma_mm", "sigma_deg", "predicted_sigma_mm",
                                      "predicted_sigma_deg")}
    elif step == "accuracy":
        out |= {"rms_dR_deg": r.get("rms_dR_deg"), "rms_dT_mm": r.get("rms_dT_mm"), "passed": r.get("passed"),
                "poses": len(r.get("rows") or [])}
    for key, value in (r.get("truth_error") or {}).items():
        out[f"truth_{key}"] = value
    return {k: v for k, v in ((k, _plain(v)) for k, v in out.items()) if v is not None}


def describe(step: str, r: dict[str, Any]) -> list[str]:
    """A short human summary of one step's result (the marks': a line per mark too; its truth error in --sim)."""
    per_item: list[str] = []
    if step == "intrinsics":
        c = r["camera"]
        line = (f"intrinsics: fx {c['fx']:.2f} fy {c['fy']:.2f} cx {c['cx']:.2f} cy {c['cy']:.2f} px, "
                f"k1 {c['k1']:.4g}; RMS {r['rms_px']:.3f} px; {len(r.get('per_image_rms_px', []))} of "
                f"{r.get('images')} images used")
        if r.get("rejected"):
            line += f" ({len(r['rejected'])} rejected)"
    elif step in ("cell", "part"):
        res = r.get("residuals_mm", {})
        worst = max(res, key=res.get) if res else "-"
        what = f"cell frame ({r.get('method')})" if step == "cell" else "part frame"
        line = f"{what}: RMS {r['rms_mm']:.3f} mm, largest {res.get(worst, 0.0):.3f} mm ({worst}), {len(res)} points"
    elif step == "marks":
        marks = r.get("marks") or []
        line = (f"reference marks: {len(marks)} surveyed, largest deviation from the nominal "
                f"{_num(r, 'max_deviation_mm', '.3f')} mm ({r.get('max_deviation_mark', '-')}), RMS "
                f"{_num(r, 'rms_deviation_mm', '.3f')} mm (tolerance {_num(r, 'tolerance_mm', 'g')} mm); their "
                "position_cf go into [[reference_marks]] with the calibration")
        per_item = [f"  {m['name']}: {' '.join(f'{v:.3f}' for v in m['position_cf'])} mm (CF), "
                    f"{m['deviation_mm']:.3f} mm from its nominal, tracker RMS {m['tracker_rms_mm']:.4f} mm"
                    for m in marks]
    elif step == "base":
        line = (f"robot base: RMS {r['rms_mm']:.3f} mm over {len(r['residuals_mm'])} poses, largest "
                f"{max(r['residuals_mm']):.3f} mm; sigma {r['sigma_mm']:.4f} mm / {r['sigma_deg']:.5f} deg; SMR on "
                f"the flange at {', '.join(f'{v:.2f}' for v in r['smr_f'])} mm")
    elif step == "sfi":
        poses = r.get("poses", [])
        spread = max((p.get("spread_mm", 0.0) for p in poses), default=0.0)
        line = (f"measuring poses: {len(poses)} SFi, largest spread {spread:.3f} mm; camera on the flange spread "
                f"{_num(r, 'T_f_c_spread_mm', '.3f')} mm / {_num(r, 'T_f_c_spread_deg', '.4f')} deg")
    elif step == "verify":
        line = (f"verification: {r.get('n')} measurements, largest excursion {_num(r, 'max_mm', '.3f')} mm / "
                f"{_num(r, 'max_deg', '.4f')} deg; predicted sigma {_num(r, 'predicted_sigma_mm', '.3f')} mm / "
                f"{_num(r, 'predicted_sigma_deg', '.4f')} deg")
    else:
        verdict = {True: "PASSED", False: "FAILED"}.get(r.get("passed"), "no verdict")
        line = (f"accuracy: RMS dR {_num(r, 'rms_dR_deg', '.4f')} deg, dT {_num(r, 'rms_dT_mm', '.3f')} mm over "
                f"{len(r.get('rows', []))} poses: {verdict}")
    lines = [line, *per_item]
    if r.get("truth_error"):
        lines.append("  error against the simulated truth: "
                     + ", ".join(f"{k} {v:.4g}" for k, v in r["truth_error"].items()))
    return lines


def _num(result: dict[str, Any], key: str, fmt: str) -> str:
    value = result.get(key)
    return format(value, fmt) if isinstance(value, (int, float)) else "?"


def _plain(value: Any) -> Any:
    """A JSON-ish value as the provenance can hold it (None: leave it out)."""
    if isinstance(value, bool | str):
        return value
    if isinstance(value, int | np.integer):
        return int(value)
    if isinstance(value, float | np.floating):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, list | tuple | np.ndarray):
        numbers = [_plain(v) for v in value]
        return numbers if all(isinstance(v, int | float) and not isinstance(v, bool) for v in numbers) else None
    return None
