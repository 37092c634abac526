"""``monoguide health``: the calibration's health from the state directory, on an empty one and on a long journal.

The journal is written with seeded residuals whose truth the test knows (view 2 of the roof drifting upwards, the
others as the noise model says); the command's means and trends are checked against that truth, its exit status
against the latch.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from monoguide.daemon.config import load_cell_config
from monoguide.daemon.cycle import Residual
from monoguide.daemon.service import CycleEntry, Journal
from monoguide.daemon.service._health import CalibrationHealth
from monoguide.solver.errors import CalibrationSuspect

SIM_CELL = Path(__file__).parents[3] / "config" / "sim-cell.toml"
CYCLES, LAST = 3000, 400


def _health(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "monoguide.daemon.cli", "health", *args], capture_output=True,
                          text=True, timeout=120)


def test_an_empty_state_directory_is_healthy_and_says_so(tmp_path: Path) -> None:
    run = _health("--state-dir", str(tmp_path), "--json")
    assert run.returncode == 0, run.stderr
    report = json.loads(run.stdout)
    assert report["latched"] is None and report["monitors"] == {} and report["jobs"] == {}
    assert report["camera_deviation"] is None  # no marks, no cycle (tests/daemon/cli/test_health_marks.py)
    text = _health("--state-dir", str(tmp_path), "--out", str(tmp_path / "health.png"))
    assert "no trend monitor yet" in text.stdout and (tmp_path / "health.png").stat().st_size > 1000
    missing = _health("--state-dir", str(tmp_path / "nowhere"))
    assert missing.returncode == 2 and "nowhere" in missing.stderr


@pytest.fixture(scope="module")
def long_journal(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, np.ndarray]:
    """A journal of CYCLES roof cycles; each view's residual per degree of freedom seeded, view 2's drifting."""
    state = tmp_path_factory.mktemp("health-state")
    rng = np.random.default_rng(33)
    drift = np.linspace(1.0, 3.0, CYCLES)  # view 2's scale: from as predicted to three times
    views = rng.chisquare(2, size=(CYCLES, 4)) / 2.0
    views[:, 1] *= drift
    with Journal(state) as journal:
        for k in range(CYCLES):
            per_view = [[float(2.0 * v), 2] for v in views[k]]
            result = {"status": "ok", "calibration_residual": {"chi2": float(2.0 * views[k].mean()), "dof": 2,
                                                                "per_view": per_view}}
            journal.commit_cycle(CycleEntry(started_at=1.7e9 + 5 * k, finished_at=1.7e9 + 5 * k + 4, job=1,
                                            part_tag=k % 65536, record={"part": "roof"}, result=result))
    return state, views


def test_the_recent_means_and_trends_are_the_journals(long_journal: tuple[Path, np.ndarray]) -> None:
    state, views = long_journal
    run = _health("--state-dir", str(state), "--last", str(LAST), "--json", "--config", str(SIM_CELL))
    assert run.returncode == 0, run.stderr  # no monitor file: nothing latched, nothing warned
    report = json.loads(run.stdout)
    (job,) = report["jobs"].values()
    assert len(job["total"]) == LAST and job["cycles"][-1] == CYCLES
    recent = views[-LAST:]
    for v in range(4):
        assert job["views"][v]["mean"] == pytest.approx(recent[:, v].mean(), rel=1e-9)
    slopes = [job["views"][v]["trend_per_100_cycles"] for v in range(4)]
    truth = np.polyfit(np.arange(CYCLES - LAST + 1, CYCLES + 1), recent[:, 1], 1)[0] * 100
    assert slopes[1] == pytest.approx(truth, rel=1e-6) and slopes[1] > 0
    assert report["days_since_calibration"] is None  # the shipped simulated cell was never calibrated by the wizard


def test_a_latched_alarm_is_reported_and_exits_1(tmp_path: Path) -> None:
    health = CalibrationHealth(tmp_path, load_cell_config(SIM_CELL))
    with pytest.raises(CalibrationSuspect):
        for k in range(1, 50):
            health.observe(1, k, "2026-12-01T10:00:00+00:00", Residual(40.0, 2))
    run = _health("--state-dir", str(tmp_path))
    assert run.returncode == 1
    assert "LATCHED CALIBRATION_SUSPECT since cycle" in run.stdout and "job 1: ALARM" in run.stdout
