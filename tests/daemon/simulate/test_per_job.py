"""A run of several part types judges each job's grasps against its own prediction: a hood whose grasps are 50 %
worse than its own (smaller) predicted sigma is not met, even where they would pass the roof's; the roof as
predicted is met. Ground truth: grasp errors drawn (seeded) from each job's predicted 3-D distribution."""

from __future__ import annotations

import numpy as np

from monoguide.daemon.simulate._summary import Targets, summarize

SIGMA = {1: 0.234, 2: 0.143}  # mm at the grasp point: the two parts' predictions ([[parts]] of config/sim-cell.toml)
VARIANCES = {job: (s * s / 3,) * 3 for job, s in SIGMA.items()}  # round: each axis a third of sigma^2


def _cycles(scale: dict[int, float], n: int, seed: int) -> list[dict]:
    rng = np.random.default_rng(seed)
    cycles = []
    for k in range(2 * n):
        job = 1 + k % 2
        error = rng.normal(0.0, np.sqrt(VARIANCES[job][0]), 3) * scale[job]
        cycles.append({"cycle": k + 1, "job": job, "status": "ok", "error_code": None, "plc_code": 0,
                       "line_outcome": "acknowledged", "journal_cycle": k + 1, "fault": None,
                       "grasp_error_mm": float(np.linalg.norm(error)), "grasp_error_deg": 0.001,
                       "offset_written": None, "timings_ms": {"overhead": 40.0, "cycle": 3000.0}})
    return cycles


def _jobs() -> dict[int, Targets]:
    return {job: Targets.for_run(False, SIGMA[job], None, VARIANCES[job]) for job in SIGMA}


def test_each_job_is_judged_against_its_own_prediction() -> None:
    summary = summarize(_cycles({1: 1.0, 2: 1.5}, 40, seed=3), [], jobs=_jobs())
    roof, hood = summary["jobs"]["1"], summary["jobs"]["2"]
    assert (roof["cycles"], hood["cycles"], roof["grasped"], hood["grasped"]) == (40, 40, 40, 40)
    assert roof["predicted_sigma_mm"] == SIGMA[1] and hood["predicted_sigma_mm"] == SIGMA[2]
    assert roof["grasp_rms_mm"] <= roof["grasp_target_mm"]  # as predicted: met
    assert hood["grasp_rms_mm"] > hood["grasp_target_mm"]  # 50 % worse than its own: not met ...
    assert hood["grasp_rms_mm"] < roof["grasp_target_mm"]  # ... though the roof's bound would have passed it
    met = {t["name"]: t["met"] for t in summary["targets"] if t["name"].startswith("grasp_")}
    assert met == {"grasp_rms_mm job 1": True, "grasp_rms_mm job 2": False}
    assert summary["grasp_target_met"] is False


def test_one_job_is_judged_as_a_run_of_one_part_type() -> None:
    cycles = [c for c in _cycles({1: 1.0, 2: 1.0}, 40, seed=4) if c["job"] == 1]
    summary = summarize(cycles, [], jobs={1: _jobs()[1]})
    assert [t["name"] for t in summary["targets"] if t["name"].startswith("grasp_")] == ["grasp_rms_mm"]
    assert summary["predicted_sigma_mm"] == SIGMA[1] and summary["grasp_vs_predicted"]["mm"]["n"] == 40
    assert summary["grasp_target_met"] is True
