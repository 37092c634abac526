"""``daemon/calibration_report.py``: the report of a seeded synthetic calibration session, whole or partial."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from monoguide.daemon.calibration_report import CHART_SIZE, FIGURES, PLAN_SIZE, REPORT_NAME, TRUTH_FIGURE, write_report
from monoguide.daemon.config import load_cell_config

CONFIG_PATH = Path(__file__).parents[2] / "config" / "sim-cell.toml"
STEPS = ("intrinsics", "cell", "base", "part", "sfi", "verify", "accuracy")


def _session(seed: int, steps: tuple[str, ...], sim: bool) -> dict[str, Any]:
    """A session as the wizard stores it (docs/calibration.md), every number drawn from ``seed``."""
    rng, config = np.random.default_rng(seed), load_cell_config(CONFIG_PATH)
    done = "2025-06-01T12:00:00+00:00"
    rows = [{"lt": rng.normal(0, 2, 6).tolist(), "mono": rng.normal(0, 2, 6).tolist(), "delta": [0.0] * 6,
             "dR_deg": float(rng.uniform(0, 0.05)), "dT_mm": float(rng.uniform(0, 0.5))} for _ in range(3)]
    results: dict[str, dict[str, Any]] = {
        "intrinsics": {"camera": config.camera.intrinsics.as_dict(), "rms_px": 0.14,
                       "per_image_rms_px": rng.uniform(0.1, 0.2, 8).tolist(), "rejected": {"5": "blurred, 6.1 px"},
                       "images": 8, "truth_error": {"focal_rel_error": 0.0004}},
        "cell": {"method": "best-fit", "T_cf_tracker": np.eye(4).tolist(),
                 "residuals_mm": {f"B{i + 1}": float(v) for i, v in enumerate(rng.uniform(0, 0.03, 3))},
                 "rms_mm": 0.02, "truth_error": {"cell_mm": 0.02, "cell_deg": 0.001}},
        "base": {"T_cf_b": config.reference.T_cf_b.tolist(), "smr_f": [0.0, 0.0, 250.0],
                 "residuals_mm": rng.uniform(0, 0.05, 16).tolist(), "rms_mm": 0.03, "sigma_mm": 0.01,
                 "sigma_deg": 0.0003, "flange_poses": [], "truth_error": {"base_mm": 0.012, "base_deg": 0.0002,
                                                                          "smr_mm": 0.01}},
        "part": {"T_cf_w0": config.reference.T_cf_w0.tolist(),
                 "residuals_mm": {n: float(v) for n, v in zip(config.part.point_names, rng.uniform(0, 0.03, 4),
                                                              strict=True)}, "rms_mm": 0.02},
        "sfi": {"poses": [{"name": p.name, "T_cf_si": p.T_cf_si.tolist(), "spread_mm": float(rng.uniform(0.1, 0.2)),
                           "spread_deg": float(rng.uniform(0.01, 0.02)), "sem_mm": 0.02, "sem_deg": 0.003,
                           "visits": 4, "deviations_mm": [0.1] * 4} for p in config.measuring_poses],
                "T_f_c": config.camera.T_f_c.tolist(), "T_f_c_spread_mm": 0.1, "T_f_c_spread_deg": 0.01,
                "truth_error": {"sfi_mm_max": 0.03, "sfi_deg_max": 0.004, "hand_eye_mm": 0.05, "hand_eye_deg": 0.004}},
        "verify": {"T_s1_w0": np.eye(4).tolist(), "sigma_mm": rng.uniform(0.05, 0.2, 3).tolist(),
                   "sigma_deg": rng.uniform(0.001, 0.02, 3).tolist(), "max_mm": 0.3, "max_deg": 0.03, "n": 5,
                   "predicted_sigma_mm": 0.191, "predicted_sigma_deg": 0.0185},
        "accuracy": {"rows": rows, "rms_dR_deg": 0.03, "rms_dT_mm": 0.3, "passed": True, "tolerance_mm": 0.5,
                     "tolerance_deg": 0.05, "markdown": "| TABLE-3-MARKER | ψ (°) |\n| :-: | --: |"},
    }
    if not sim:
        for result in results.values():
            result.pop("truth_error", None)
    return {"format": "monoguide.calibration-session/1", "config": str(CONFIG_PATH), "sim": sim,
            "started": done, "devices": {"camera": "sim camera SIM-1", "tracker": "sim tracker LT-1"},
            "options": {"placements": 2, "visits": 2},
            "steps": {s: results[s] | {"done": done} for s in steps},
            "refused": {} if "base" in steps else {"base": {"code": "CALIBRATION_DEGENERATE", "plc_code": 701,
                                                            "message": "poses on a line", "at": done}}}


def _pictures(directory: Path) -> dict[str, tuple[int, int]]:
    out = {}
    for path in directory.glob("*.png"):
        with Image.open(path) as image:
            image.load()  # decodes the whole file
            out[path.name] = image.size
    return out


def test_a_whole_simulated_session_gives_every_figure(tmp_path: Path) -> None:
    session = _session(seed=4, steps=STEPS, sim=True)
    out = write_report(tmp_path / "report", session)
    assert out == tmp_path / "report" / REPORT_NAME
    text = out.read_text()
    expected = {name for step in STEPS for name in FIGURES[step]} | {TRUTH_FIGURE}
    sizes = _pictures(out.parent)
    assert set(sizes) == expected
    wide = {"measuring-poses.png", "uncertainty-map.png"}
    assert all(size == (PLAN_SIZE if name in wide else CHART_SIZE) for name, size in sizes.items())
    for name in expected:
        assert f"![{name}]({name})" in text
    assert "TABLE-3-MARKER" in text and "**passed**" in text and "sim camera SIM-1" in text
    assert "| base | base_mm | 0.012 | 0.05 |" in text  # the truth error beside the target
    assert "| S4 |" in text and "blurred, 6.1 px" in text
    # the measuring poses are drawn: the plan is not blank where the cameras are
    with Image.open(out.parent / "measuring-poses.png") as image:
        assert len(np.unique(np.asarray(image.convert("RGB")).reshape(-1, 3), axis=0)) > 5


def test_a_partial_real_session_reports_only_its_steps(tmp_path: Path) -> None:
    session = _session(seed=7, steps=("intrinsics", "cell", "part"), sim=False)
    out = write_report(tmp_path, session)
    text = out.read_text()
    sizes = _pictures(tmp_path)
    assert set(sizes) == {"intrinsics-residuals.png", "residuals-cell.png", "residuals-part.png"}
    assert all(size == CHART_SIZE for size in sizes.values())
    for step in ("base", "sfi", "verify", "accuracy"):
        assert all(name not in text for name in FIGURES[step])
    assert TRUTH_FIGURE not in text and "simulated truth" not in text
    assert "**refused**" in text and "poses on a line" in text and "| 6 Verification | not done | |" in text
    assert "| P3 |" in text and "| B2 |" in text
