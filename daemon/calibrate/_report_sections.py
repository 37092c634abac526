"""What the calibration report shows of each step: its title, its figures, the issue's targets on the simulated
cell, and how a value is written (the Markdown's and the figures' labels alike)."""

from __future__ import annotations

import math
from typing import Any

REPORT_NAME = "calibration-report.md"
# step -> the figures its section shows (truth-errors.png: --sim, every step with a truth_error)
FIGURES: dict[str, tuple[str, ...]] = {
    "intrinsics": ("intrinsics-residuals.png",),
    "cell": ("residuals-cell.png",),
    "marks": ("marks-deviation.png",),
    "base": ("residuals-base.png",),
    "part": ("residuals-part.png",),
    "sfi": ("sfi-spread.png", "measuring-poses.png", "uncertainty-map.png"),
    "verify": ("repeatability.png",),
    "accuracy": ("accuracy.png",),
}
TRUTH_FIGURE = "truth-errors.png"
# the issue's targets on the simulated cell, for the truth errors' plot
TRUTH_TARGETS = {"focal_rel_error": 0.001, "base_mm": 0.05, "base_deg": 0.005, "sfi_mm_max": 0.05,
                 "sfi_deg_max": 0.01}
TITLES = {"intrinsics": "1 Camera intrinsics", "cell": "2 Cell frame CF", "marks": "2a Reference marks",
          "base": "3 Robot base BF",
          "part": "4 Part frame WF and T_cf_w0", "sfi": "5 Measuring-pose frames SFi", "verify": "6 Verification",
          "accuracy": "7 Accuracy validation (Table 3)"}


def shown(value: Any) -> str:
    """A value as the report writes it: 4 significant digits, ``-`` for none (or not finite), yes / no."""
    if value is None:
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.4g}" if math.isfinite(value) else "-"
    if isinstance(value, list | tuple):
        return "[" + ", ".join(shown(v) for v in value) + "]"
    return str(value)
