"""``monoguide health``'s camera pose from the reference marks: per view its deviation from the calibrated pose over
the recent cycles, the robot's repeatability told from a drift (docs/health.md, "Camera pose with reference marks").

Every cycle of a cell with marks journals ``result["camera_deviation"]``: per view (measuring-pose order) the
camera's estimated deviation in its axes (``d_mm``, ``w_deg``, their norms ``mm``, ``deg``), whether the view was
``checked`` (two marks or more) and the tolerance along the observed direction (``tolerance_mm``,
``tolerance_deg``: the deviation is beyond it exactly when the cycle's marks test refuses it). The check job
(65535) journals the same. Cycles are taken whatever their outcome: a cycle refused for its camera's deviation is
the one that matters most. Per view, of its checked cycles in the window, :func:`summarise` gives the scatter, the
mean and the trend per 1,000 cycles of the translation and of the rotation (``solver.trend_pose``), the cycles
beyond tolerance and a one-line verdict.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from monoguide.daemon.service import JournalRow
from monoguide.solver.trend_pose import SIGNIFICANT_SIGMAS, VectorTrend, cycles_to_reach, vector_trend

KEY = "camera_deviation"
PER_CYCLES = 1000.0
NO_MARKS = "no reference marks in this cell: the camera's pose is not measured each cycle (docs/cycle-marks.md)"


def summarise(rows: Sequence[JournalRow], window: int) -> dict[str, Any] | None:
    """The ``camera_deviation`` section of the report from ``rows`` (oldest first, the window already cut); None
    when no row carries the key (a cell without marks, or an empty journal)."""
    series: dict[str, dict[str, list]] = {}
    carrying = []
    for row in rows:
        entries = row.result.get(KEY) if isinstance(row.result, dict) else None
        if not isinstance(entries, list):
            continue
        carrying.append(row.number)
        for entry in entries:
            parsed = _entry(entry)
            if parsed is None:
                continue
            view = series.setdefault(parsed["view"], {"cycles": [], "d_mm": [], "w_deg": [], "tolerance_mm": [],
                                                      "tolerance_deg": [], "failed": [], "unchecked": []})
            if not parsed["checked"]:
                view["unchecked"].append(row.number)
                continue
            view["cycles"].append(row.number)
            view["d_mm"].append(parsed["d_mm"])
            view["w_deg"].append(parsed["w_deg"])
            view["tolerance_mm"].append(parsed["tolerance_mm"])
            view["tolerance_deg"].append(parsed["tolerance_deg"])
            view["failed"].append(row.status != "ok")
    if not carrying:
        return None
    views = [_view(name, s) for name, s in series.items()]
    return {"window": window, "cycles": len(carrying), "first_cycle": carrying[0], "last_cycle": carrying[-1],
            "per_cycles": PER_CYCLES, "significant_sigmas": SIGNIFICANT_SIGMAS,
            "warning": any(v["state"] in ("drifting", "beyond_tolerance") for v in views), "views": views}


def _entry(entry: Any) -> dict[str, Any] | None:
    """One view's entry, checked for shape and finite numbers (None: unusable, skipped)."""
    if not isinstance(entry, dict) or not isinstance(entry.get("view"), str):
        return None
    if entry.get("checked") is not True:
        return {"view": entry["view"], "checked": False}
    try:
        d = np.asarray(entry["d_mm"], dtype=float).reshape(3)
        w = np.asarray(entry["w_deg"], dtype=float).reshape(3)
        tol_mm, tol_deg = float(entry["tolerance_mm"]), float(entry["tolerance_deg"])
    except (KeyError, TypeError, ValueError):
        return None
    if not (np.all(np.isfinite(d)) and np.all(np.isfinite(w))) or math.isnan(tol_mm) or math.isnan(tol_deg):
        return None
    return {"view": entry["view"], "checked": True, "d_mm": d, "w_deg": w, "tolerance_mm": tol_mm,
            "tolerance_deg": tol_deg}


def _view(name: str, s: dict[str, list]) -> dict[str, Any]:
    n = len(s["cycles"])
    out: dict[str, Any] = {"view": name, "n": n, "unchecked": len(s["unchecked"]), "cycles": s["cycles"]}
    if n == 0:
        out.update({"mm": [], "deg": [], "tolerance_mm": [], "tolerance_deg": [], "translation": None,
                    "rotation": None, "tolerance": None, "share_of_tolerance": None, "beyond_tolerance": None,
                    "failed_cycles": 0, "state": "unchecked",
                    "verdict": f"not checked: fewer than 2 marks seen in its {len(s['unchecked'])} cycles of the "
                    "window"})
        return out
    cycles = np.array(s["cycles"], dtype=float)
    d, w = np.array(s["d_mm"]), np.array(s["w_deg"])
    tol_mm, tol_deg = np.array(s["tolerance_mm"]), np.array(s["tolerance_deg"])
    mm, deg = np.linalg.norm(d, axis=1), np.linalg.norm(w, axis=1)
    share = np.fmax(_ratio(mm, tol_mm), _ratio(deg, tol_deg))  # 1: at the tolerance (the two agree: one direction)
    beyond = share > 1.0
    trailing = int(np.argmin(beyond[::-1])) if not beyond.all() else n
    translation, rotation = vector_trend(cycles, d, PER_CYCLES), vector_trend(cycles, w, PER_CYCLES)
    tolerance = {"mm": _median(tol_mm), "deg": _median(tol_deg)}
    out.update({
        "mm": mm.tolist(), "deg": deg.tolist(), "tolerance_mm": tol_mm.tolist(), "tolerance_deg": tol_deg.tolist(),
        "translation": _trend(translation, cycles[-1], tolerance["mm"], "d_mm"),
        "rotation": _trend(rotation, cycles[-1], tolerance["deg"], "w_deg"),
        "tolerance": tolerance,
        "share_of_tolerance": {"mean": float(np.mean(share)), "max": float(np.max(share)), "last": float(share[-1])},
        "beyond_tolerance": {"cycles": int(beyond.sum()), "last_consecutive": trailing,
                             "last_cycle": int(cycles[beyond][-1]) if beyond.any() else None},
        "failed_cycles": int(np.sum(np.array(s["failed"]))),
    })
    out.update(_verdict(out, translation, rotation))
    return out


def _ratio(value: np.ndarray, tolerance: np.ndarray) -> np.ndarray:
    """value / tolerance; 0 where the tolerance is infinite or not positive (nothing to compare with)."""
    ok = np.isfinite(tolerance) & (tolerance > 0)
    return np.where(ok, value / np.where(ok, tolerance, 1.0), 0.0)


def _median(values: np.ndarray) -> float | None:
    finite = values[np.isfinite(values) & (values > 0)]
    return float(np.median(finite)) if finite.size else None


def _trend(t: VectorTrend, last: float, tolerance: float | None, axes: str) -> dict[str, Any]:
    """One of translation (mm) and rotation (deg) as the JSON has it."""
    slope = None
    if t.slope is not None:
        reach = None if tolerance is None or not t.significant() else cycles_to_reach(t, last, tolerance)
        slope = {axes: t.slope.tolist(), f"{axes}_se": t.slope_se.tolist() if t.slope_se is not None else None,
                 "norm": t.slope_norm, "norm_se": t.slope_norm_se, "statistic": _finite(t.statistic), "dof": t.dof,
                 "p_value": t.p_value, "sigmas": _finite(t.sigmas), "significant": t.significant(),
                 "cycles_to_tolerance": reach}
    return {"mean": {axes: t.mean.tolist(), "norm": t.mean_norm},
            "scatter": None if t.scatter is None else {axes: t.scatter.tolist(), "norm": t.scatter_norm},
            "trend_per_1000_cycles": slope}


def _finite(value: float | None) -> float | None:
    """Strict JSON has no infinity: a certain slope (nothing scatters) is written as 1e9."""
    return None if value is None else min(value, 1e9)


def _verdict(view: dict[str, Any], translation: VectorTrend, rotation: VectorTrend) -> dict[str, str]:
    beyond, n = view["beyond_tolerance"], view["n"]
    drifts = [f"{t.slope_norm:.3g} {unit} / 1000 cycles" for t, unit in ((translation, "mm"), (rotation, "deg"))
              if t.significant() and t.slope_norm is not None]
    if beyond["last_consecutive"]:
        text = f"beyond tolerance in the last {beyond['last_consecutive']} cycles"
        return {"state": "beyond_tolerance", "verdict": text + (f" (drifting {', '.join(drifts)})" if drifts else "")}
    if beyond["cycles"]:
        text = (f"beyond tolerance in {beyond['cycles']} of its last {n} cycles (last at cycle "
                f"{beyond['last_cycle']}, within since)")
        return {"state": "beyond_tolerance", "verdict": text + (f"; drifting {', '.join(drifts)}" if drifts else "")}
    if drifts:
        reach = [r for r in (view["translation"]["trend_per_1000_cycles"]["cycles_to_tolerance"],
                             view["rotation"]["trend_per_1000_cycles"]["cycles_to_tolerance"]) if r is not None]
        return {"state": "drifting", "verdict": f"drifting {', '.join(drifts)}"
                + (f" (the tolerance reached in about {min(reach):.0f} cycles at this rate)" if reach else "")}
    if translation.slope is None:
        return {"state": "too_few_cycles", "verdict": f"within tolerance; too few cycles ({n}) for a trend"}
    return {"state": "repeatability", "verdict": "repeatability only"}


def lines(section: dict[str, Any] | None, *, journal_empty: bool, configured_marks: int | None) -> list[str]:
    """The text report's lines of the section."""
    if section is None:
        if journal_empty:
            return ["  camera pose: no cycle journaled yet"]
        if configured_marks:
            return [f"  camera pose: the cell has {configured_marks} reference marks, but no cycle in the window "
                    "journaled the camera's deviation (docs/cycle-marks.md)"]
        return ["  " + NO_MARKS]
    out = [f"  camera pose from the reference marks, over the {section['cycles']} cycles measuring it in the last "
           f"{section['window']} (cycles {section['first_cycle']}-{section['last_cycle']}); a trend is a drift when "
           f"significant beyond {section['significant_sigmas']:g} sigma (its three components tested together):"]
    for view in section["views"]:
        out.append(f"    view {view['view']}: {view['verdict']}")
        if not view["n"]:
            continue
        tol = view["tolerance"]
        for kind, unit, axes, digits, bound in (("translation", "mm", "d_mm", 3, tol["mm"]),
                                                ("rotation", "deg", "w_deg", 4, tol["deg"])):
            t = view[kind]
            parts = [f"mean {t['mean']['norm']:.{digits}f} {unit}"]
            if t["scatter"] is not None:
                parts.append("scatter (x y z) " + " ".join(f"{v:.{digits}f}" for v in t["scatter"][axes])
                             + f" {unit}")
            slope = t["trend_per_1000_cycles"]
            if slope is not None:
                parts.append(f"trend {slope['norm']:.{digits}f} ± {slope['norm_se']:.{digits}f} {unit} / 1000 cycles"
                             f" (significance {slope['sigmas']:.1f} sigma)")
            if bound is not None:
                parts.append(f"tolerance {bound:.{digits}f} {unit} (median)")
            out.append(f"      {kind}: " + ", ".join(parts))
        beyond = view["beyond_tolerance"]
        out.append(f"      {view['share_of_tolerance']['max']:.0%} of the tolerance at most, "
                   f"{view['share_of_tolerance']['mean']:.0%} on average; {beyond['cycles']} cycles beyond it"
                   + (f"; {view['failed_cycles']} of its cycles failed" if view["failed_cycles"] else "")
                   + (f"; {view['unchecked']} cycles unchecked (fewer than 2 marks)" if view["unchecked"] else ""))
    return out
