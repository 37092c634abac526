"""``daemon/calibrate/_report.py``: the report of a seeded synthetic calibration session, whole or partial."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from helpers.figure_checks import assert_readable, capture, unit
from PIL import Image

from monoguide.daemon.calibrate import CHART_SIZE, FIGURES, PLAN_SIZE, REPORT_NAME, TRUTH_FIGURE, write_report
from monoguide.daemon.calibrate import _report as calibration_report
from monoguide.daemon.config import load_cell_config

CONFIG_PATH = Path(__file__).parents[3] / "config" / "sim-cell.toml"
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


@pytest.fixture(scope="module")
def whole(tmp_path_factory: pytest.TempPathFactory) -> tuple[dict[str, Any], Path, dict[str, dict[str, Any]]]:
    """A whole simulated session's report, written once: the session, the Markdown's path and what each
    figure showed just before it was written."""
    session = _session(seed=4, steps=STEPS, sim=True)
    with pytest.MonkeyPatch.context() as patch:
        seen = capture(patch, calibration_report)
        out = write_report(tmp_path_factory.mktemp("whole") / "report", session)
    return session, out, seen


def test_a_whole_simulated_session_gives_every_figure(whole) -> None:
    _, out, _ = whole
    assert out.name == REPORT_NAME and out.parent.name == "report"
    text = out.read_text()
    expected = {name for step in STEPS for name in FIGURES[step]} | {TRUTH_FIGURE}
    sizes = _pictures(out.parent)
    assert set(sizes) == expected
    wide = {"measuring-poses.png", "uncertainty-map.png"}
    assert all(size == (PLAN_SIZE if name in wide else CHART_SIZE) for name, size in sizes.items())
    assert all((out.parent / name).stat().st_size < 300_000 for name in expected)
    for name in expected:
        assert f"![{name}]({name})" in text
    assert "TABLE-3-MARKER" in text and "**passed**" in text and "sim camera SIM-1" in text
    assert "| base | base_mm | 0.012 | 0.05 |" in text  # the truth error beside the target
    assert "| S4 |" in text and "blurred, 6.1 px" in text
    # the measuring poses are drawn: the plan is not blank where the cameras are
    with Image.open(out.parent / "measuring-poses.png") as image:
        assert len(np.unique(np.asarray(image.convert("RGB")).reshape(-1, 3), axis=0)) > 5


# the unit of each plotting axes' y label (left, then a right-hand twin or the next panel) and of each colour bar
UNITS = {
    "intrinsics-residuals.png": (["px"], []),
    "residuals-cell.png": (["mm"], []),
    "residuals-base.png": (["mm"], []),
    "residuals-part.png": (["mm"], []),
    "sfi-spread.png": (["mm", "deg"], []),
    "measuring-poses.png": (["mm", "mm"], []),
    "uncertainty-map.png": (["mm", "mm"], ["mm", "deg"]),
    "repeatability.png": (["mm", "deg"], []),
    "accuracy.png": (["mm", "deg"], []),
    "truth-errors.png": ([None], []),  # a ratio to the target
}


def test_every_figure_names_its_quantities_and_units(whole) -> None:
    _, _, seen = whole
    assert set(seen) == set(UNITS)
    for name, (y_units, bar_units) in UNITS.items():
        figure = seen[name]
        assert_readable(figure)
        assert [unit(ax["y"]) for ax in figure["axes"]] == y_units, name
        assert [unit(label) for label, *_ in figure["colorbars"]] == bar_units, name
        assert all(ax["x"] for ax in figure["axes"] if ax["x"] is not None), name
    # multi-series charts carry a legend: bars beside their RMS / tolerance / prediction, or mm beside deg
    for name in ("residuals-cell.png", "sfi-spread.png", "repeatability.png", "accuracy.png", "truth-errors.png"):
        assert len(seen[name]["legend"]) >= 2, name
    for name in ("measuring-poses.png", "uncertainty-map.png"):  # drawings of the cell and maps over it: to scale
        assert all(ax["equal"] and unit(ax["x"]) == "mm" for ax in seen[name]["axes"]), name


def test_the_figures_show_the_sessions_numbers(whole) -> None:
    session, _, seen = whole
    steps, config = session["steps"], load_cell_config(CONFIG_PATH)
    (part,) = seen["residuals-part.png"]["axes"]
    assert part["xticks"] == list(config.part.point_names)
    np.testing.assert_allclose(part["bars"][0], list(steps["part"]["residuals_mm"].values()))
    assert part["points"]["RMS, 0.02 mm"][1].tolist() == [0.02, 0.02]
    bars, dots = seen["accuracy.png"]["axes"]
    np.testing.assert_allclose(bars["bars"][0], [row["dT_mm"] for row in steps["accuracy"]["rows"]])
    np.testing.assert_allclose(dots["points"]["dR, rotation (deg, right)"][1],
                               [row["dR_deg"] for row in steps["accuracy"]["rows"]])
    assert bars["points"]["tolerance, 0.5 mm"][1][0] == 0.5 and bars["ylim"][1] > 0.5
    assert dots["points"]["tolerance, 0.05 deg"][1][0] == 0.05 and dots["ylim"][1] > 0.05
    mm, deg = seen["repeatability.png"]["axes"]
    np.testing.assert_allclose(mm["bars"][0], steps["verify"]["sigma_mm"])
    assert mm["xticks"] == ["x", "y", "z"] and deg["xticks"] == ["rx", "ry", "rz"]
    assert mm["points"]["planner's predicted σ, 0.191 mm"][1][0] == 0.191
    (truth,) = seen["truth-errors.png"]["axes"]
    ratio = dict(zip(truth["xticks"], truth["bars"][0], strict=True))
    assert ratio["base_mm"] == pytest.approx(0.012 / 0.05) and ratio["focal_rel_error"] == pytest.approx(0.4)
    assert ratio["hand_eye_mm"] == 0.0  # no target: no bar
    above, side = seen["measuring-poses.png"]["axes"]
    holes = np.column_stack(above["points"]["featured hole"])
    np.testing.assert_allclose(holes, config.part.points_w[:, :2])
    np.testing.assert_allclose(side["points"]["featured hole"][1], config.part.points_w[:, 2])
    assert [e.split(":")[0] for e in seen["measuring-poses.png"]["legend"] if e.startswith("S")] == \
        ["S1", "S2", "S3", "S4"]


def test_the_uncertainty_map_spans_its_values_around_the_predicted_sigma(whole) -> None:
    """The colour scales run from each map's smallest to its largest value; at the reference part (no shift)
    the map is the simulated cell's camera-centred prediction at 0.1 px, 0.05 mm / 0.01 deg: 0.191 mm and
    0.0185 deg (docs/planning.md)."""
    _, _, seen = whole
    mm_bar, deg_bar = seen["uncertainty-map.png"]["colorbars"]
    (mm_label, mm_low, mm_high, mm_values), (_, deg_low, deg_high, deg_values) = mm_bar, deg_bar
    assert (mm_low, mm_high) == (mm_values.min(), mm_values.max()) and mm_high > mm_low
    assert (deg_low, deg_high) == (deg_values.min(), deg_values.max()) and deg_high > deg_low
    assert mm_values.shape == (11, 11) and "grasp point" in mm_label
    assert mm_values[5, 5] == pytest.approx(0.191, rel=0.005)
    assert deg_values[5, 5] == pytest.approx(0.0185, rel=0.005)
    left = seen["uncertainty-map.png"]["axes"][0]
    assert left["xlim"] == pytest.approx((-55.0, 55.0)) and left["ylim"] == pytest.approx((-55.0, 55.0))  # +-50 mm


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
