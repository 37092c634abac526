"""``monoguide health`` with reference marks: each view's camera deviation over the recent cycles, the robot's
repeatability told from a drift.

The journal is written by the service's own writer (``Journal.commit_cycle``) with seeded deviations whose truth the
test knows: every view scatters by its repeatability, cycle to cycle; view S3's camera starts drifting linearly at
cycle DRIFT_FROM, before the window, so that the window's slope is the generated one. The command must call S3
drifting with that slope (within its standard error), and no other view; a view going beyond its tolerance in the
last cycles, a cell without marks and an empty journal are reported as such.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from monoguide.daemon.cli import _health_marks
from monoguide.daemon.cli._health_marks import NO_MARKS
from monoguide.daemon.cli.health import gather
from monoguide.daemon.config import load_cell_config
from monoguide.daemon.service import CycleEntry, Journal, JournalRow
from monoguide.solver.errors import CalibrationSuspect
from monoguide.solver.trend_pose import cycles_to_reach, vector_trend

SIM_CELL_MARKS = Path(__file__).parents[3] / "config" / "sim-cell-marks.toml"
CYCLES, LAST, DRIFT_FROM = 1500, 400, 700
VIEWS = ("S1", "S2", "S3", "S4")
SIGMA_MM = np.array([0.03, 0.03, 0.015])  # the repeatability's scatter of the camera's position, per camera axis
SIGMA_DEG = np.array([0.004, 0.004, 0.002])
DRIFT_MM = np.array([0.12, -0.09, 0.0])  # view S3, per 1000 cycles from DRIFT_FROM: 0.15 mm / 1000 cycles
DRIFT_DEG = np.array([0.0, 0.0, 0.02])
TOLERANCE_MM, TOLERANCE_DEG = 0.5, 0.06
CHECK_EVERY, UNCHECKED_EVERY = 50, 10  # a check job (65535) every 50th cycle; S4 sees too few marks every 10th


def _health(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "monoguide.daemon.cli", "health", *args], capture_output=True,
                          text=True, timeout=120)


def _report(state: Path, *args: str) -> dict:
    """The report as ``--json`` prints it, in-process (the command's exit status and text are checked end to end
    through ``_health``)."""
    last = int(args[1]) if args[:1] == ("--last",) else 200
    return json.loads(json.dumps(gather(state, last)))


def _entry(view: str, d: np.ndarray, w: np.ndarray, tol_mm: float, tol_deg: float, checked: bool = True) -> dict:
    if not checked:
        d, w = np.zeros(3), np.zeros(3)
    return {"view": view, "checked": checked, "mm": float(np.linalg.norm(d)), "deg": float(np.linalg.norm(w)),
            "d_mm": d.tolist(), "w_deg": w.tolist(), "tolerance_mm": tol_mm, "tolerance_deg": tol_deg}


def _result(deviation: list[dict]) -> dict:
    return {"status": "ok", "calibration_residual": {"chi2": 2.0, "dof": 2, "per_view": [[0.5, 0.5]] * 4},
            "camera_deviation": deviation}


def _commit(journal: Journal, k: int, result: dict, *, job: int = 1, error: Exception | None = None) -> None:
    journal.commit_cycle(CycleEntry(started_at=1.7e9 + 5 * k, finished_at=1.7e9 + 5 * k + 4, job=job,
                                    part_tag=k % 65536, record={"part": "roof"}, result=result, error=error))


@pytest.fixture(scope="module")
def drifting_journal(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    """CYCLES cycles of the four views (S3 drifting from DRIFT_FROM); returns the state and the generated truth."""
    state = tmp_path_factory.mktemp("health-marks")
    rng = np.random.default_rng(2026)
    d = rng.normal(0.0, SIGMA_MM, size=(CYCLES, 4, 3))
    w = rng.normal(0.0, SIGMA_DEG, size=(CYCLES, 4, 3))
    cycles = np.arange(1, CYCLES + 1)
    since = np.clip(cycles - DRIFT_FROM, 0, None)[:, None] / 1000.0
    d[:, 2] += since * DRIFT_MM
    w[:, 2] += since * DRIFT_DEG
    tol = 1.0 + 0.1 * rng.uniform(-1, 1, size=(CYCLES, 4))  # the tolerance along the observed direction varies
    checked = np.ones((CYCLES, 4), dtype=bool)
    checked[::UNCHECKED_EVERY, 3] = False
    with Journal(state) as journal:
        for k in range(CYCLES):
            deviation = [_entry(v, d[k, i], w[k, i], TOLERANCE_MM * tol[k, i], TOLERANCE_DEG * tol[k, i],
                                bool(checked[k, i])) for i, v in enumerate(VIEWS)]
            _commit(journal, k, _result(deviation), job=65535 if (k + 1) % CHECK_EVERY == 0 else 1)
    return state, {"d": d, "w": w, "checked": checked}


@pytest.fixture(scope="module")
def drifting_report(drifting_journal: tuple[Path, dict]) -> tuple[subprocess.CompletedProcess[str], dict]:
    state, _ = drifting_journal
    run = _health("--state-dir", str(state), "--last", str(LAST), "--json")
    return run, json.loads(run.stdout)


def test_the_drifting_view_is_found_with_the_slope_generated(drifting_report: tuple) -> None:
    run, report = drifting_report
    assert run.returncode == 1, run.stderr  # a drifting camera is a warning
    section = report["camera_deviation"]
    assert section["cycles"] == LAST and section["last_cycle"] == CYCLES and section["first_cycle"] == CYCLES - LAST + 1
    assert section["warning"] is True and section["per_cycles"] == 1000.0 and section["significant_sigmas"] == 3.0
    s3 = {v["view"]: v for v in section["views"]}["S3"]
    assert s3["state"] == "drifting" and s3["verdict"].startswith("drifting ")
    for kind, axes, truth in (("translation", "d_mm", DRIFT_MM), ("rotation", "w_deg", DRIFT_DEG)):
        slope = s3[kind]["trend_per_1000_cycles"]
        assert slope["significant"] and slope["sigmas"] > 5.0
        fitted, se = np.array(slope[axes]), np.array(slope[f"{axes}_se"])
        assert np.all(np.abs(fitted - truth) < 3.0 * se), (kind, fitted, truth, se)
        assert abs(slope["norm"] - np.linalg.norm(truth)) < 3.0 * slope["norm_se"]
    assert "0.15" in s3["verdict"] or "0.14" in s3["verdict"] or "0.16" in s3["verdict"]
    # the scatter about the fitted line is the repeatability, the drift taken out
    assert np.array(s3["translation"]["scatter"]["d_mm"]) == pytest.approx(SIGMA_MM, rel=0.15)
    assert np.array(s3["rotation"]["scatter"]["w_deg"]) == pytest.approx(SIGMA_DEG, rel=0.15)


def test_the_other_views_are_repeatability_only(drifting_journal: tuple[Path, dict], drifting_report: tuple) -> None:
    _, truth = drifting_journal
    _, report = drifting_report
    views = {v["view"]: v for v in report["camera_deviation"]["views"]}
    assert list(views) == list(VIEWS)  # measuring-pose order
    for i, name in enumerate(VIEWS):
        view = views[name]
        if name == "S3":
            continue
        assert view["state"] == "repeatability" and view["verdict"] == "repeatability only", view["verdict"]
        assert not view["translation"]["trend_per_1000_cycles"]["significant"]
        assert not view["rotation"]["trend_per_1000_cycles"]["significant"]
        window = slice(CYCLES - LAST, CYCLES)
        ok = truth["checked"][window, i]
        assert view["n"] == ok.sum() and view["unchecked"] == (~ok).sum()
        assert view["translation"]["mean"]["d_mm"] == pytest.approx(truth["d"][window, i][ok].mean(axis=0), abs=1e-12)
        assert view["rotation"]["scatter"]["w_deg"] == pytest.approx(truth["w"][window, i][ok].std(axis=0, ddof=2),
                                                                     rel=0.05)
        assert np.array(view["translation"]["scatter"]["d_mm"]) == pytest.approx(SIGMA_MM, rel=0.15)
        assert view["beyond_tolerance"] == {"cycles": 0, "last_consecutive": 0, "last_cycle": None}
        assert 0 < view["share_of_tolerance"]["max"] < 1.0
        assert view["tolerance"]["mm"] == pytest.approx(TOLERANCE_MM, rel=0.05)
        assert len(view["cycles"]) == len(view["mm"]) == len(view["tolerance_deg"]) == view["n"]
    assert views["S4"]["unchecked"] == LAST // UNCHECKED_EVERY  # the zeros of an unchecked view are left out


def test_the_text_and_the_figure(drifting_journal: tuple[Path, dict], tmp_path: Path) -> None:
    state, _ = drifting_journal
    png = tmp_path / "health.png"
    run = _health("--state-dir", str(state), "--last", str(LAST), "--out", str(png))
    assert run.returncode == 1, run.stderr
    assert f"camera pose from the reference marks, over the {LAST} cycles" in run.stdout
    assert "view S3: drifting" in run.stdout and "view S1: repeatability only" in run.stdout
    assert "view S4: repeatability only" in run.stdout and "40 cycles unchecked" in run.stdout
    assert png.stat().st_size > 10_000
    with Image.open(png) as image:
        assert image.size == (900, 4 * 420)  # the residual of jobs 1 and 65535, the deviation in mm and in deg


def test_a_view_beyond_its_tolerance_in_the_last_cycles(tmp_path: Path) -> None:
    rng = np.random.default_rng(7)
    with Journal(tmp_path) as journal:
        for k in range(60):
            beyond = k >= 56
            deviation = []
            for v in VIEWS:
                d, w = rng.normal(0.0, SIGMA_MM), rng.normal(0.0, SIGMA_DEG)
                if beyond and v == "S2":
                    d, w = np.array([0.0, 0.0, 1.5 * TOLERANCE_MM]), np.array([1.5 * TOLERANCE_DEG, 0.0, 0.0])
                deviation.append(_entry(v, d, w, TOLERANCE_MM, TOLERANCE_DEG))
            error = CalibrationSuspect("view S2: the camera stood 0.75 mm / 0.090 deg ...") if beyond else None
            _commit(journal, k, {"camera_deviation": deviation} if beyond else _result(deviation), error=error)
    views = {v["view"]: v for v in _report(tmp_path)["camera_deviation"]["views"]}
    s2 = views["S2"]
    assert s2["state"] == "beyond_tolerance" and s2["verdict"].startswith("beyond tolerance in the last 4 cycles")
    assert s2["beyond_tolerance"] == {"cycles": 4, "last_consecutive": 4, "last_cycle": 60}
    assert s2["failed_cycles"] == 4 and s2["share_of_tolerance"]["max"] == pytest.approx(1.5)
    assert views["S1"]["beyond_tolerance"]["cycles"] == 0
    png = tmp_path / "health.png"
    run = _health("--state-dir", str(tmp_path), "--out", str(png))
    assert run.returncode == 1 and "view S2: beyond tolerance in the last 4 cycles" in run.stdout
    assert "4 of its cycles failed" in run.stdout and png.stat().st_size > 10_000


def test_a_cell_without_marks(tmp_path: Path) -> None:
    with Journal(tmp_path) as journal:
        for k in range(20):
            _commit(journal, k, {"status": "ok", "calibration_residual": {"chi2": 2.0, "dof": 2,
                                                                          "per_view": [[0.5, 0.5]] * 4}})
    report = _report(tmp_path)
    assert report["camera_deviation"] is None and report["cycles_in_window"] == 20
    png = tmp_path / "health.png"
    run = _health("--state-dir", str(tmp_path), "--out", str(png))
    assert run.returncode == 0 and NO_MARKS in run.stdout
    with Image.open(png) as image:
        assert image.size == (900, 420)  # no deviation panels
    marks = len(load_cell_config(SIM_CELL_MARKS).reference_marks)
    configured = gather(tmp_path, 200, SIM_CELL_MARKS)
    assert configured["reference_marks"] == marks and configured["camera_deviation"] is None
    assert f"the cell has {marks} reference marks, but no cycle in the window journaled" in " ".join(
        _health_marks.lines(None, journal_empty=False, configured_marks=marks))


def test_an_empty_journal(tmp_path: Path) -> None:
    assert _report(tmp_path)["camera_deviation"] is None  # no journal at all
    Journal(tmp_path).close()  # a journal without a cycle
    assert _report(tmp_path)["camera_deviation"] is None
    run = _health("--state-dir", str(tmp_path), "--json")
    assert run.returncode == 0 and json.loads(run.stdout)["camera_deviation"] is None, run.stderr
    assert _health_marks.lines(None, journal_empty=True, configured_marks=None) == [
        "  camera pose: no cycle journaled yet"]


def test_the_drift_test_false_alarms_at_its_rate_and_reaches_the_tolerance() -> None:
    """solver.trend_pose: without a drift, a slope called significant 0.27 % of the time (3 standard errors)."""
    rng = np.random.default_rng(11)
    cycles = np.arange(1, 201)
    calls = [vector_trend(cycles, rng.normal(0.0, SIGMA_MM, size=(200, 3))).significant() for _ in range(1000)]
    assert sum(calls) <= 8  # 2.7 expected of 1000 (more than 8 in 0.3 % of seeds)
    flat = vector_trend(cycles, np.tile([0.1, 0.0, 0.0], (200, 1)))
    assert flat.p_value == 1.0 and not flat.significant()
    line = vector_trend(cycles, np.outer(cycles, [1e-4, 0.0, 0.0]))
    assert line.sigmas == np.inf and line.slope == pytest.approx([0.1, 0.0, 0.0])
    assert cycles_to_reach(line, 200, 0.05) == pytest.approx(300.0)  # 0.02 mm at cycle 200, 1e-4 mm a cycle
    few = vector_trend(cycles[:4], np.zeros((4, 3)))
    assert few.slope is None and few.sigmas is None and not few.significant()


def test_unusable_entries_are_skipped() -> None:
    """An entry of the wrong shape, with a NaN or without a view is left out; the rest of its cycle is kept."""
    good = _entry("S1", np.array([0.01, 0.0, 0.0]), np.array([0.0, 0.001, 0.0]), TOLERANCE_MM, TOLERANCE_DEG)
    bad = [{"view": "S1", "checked": True, "d_mm": [0.1, 0.2]}, {"checked": True}, "S1",
           {**good, "w_deg": [float("nan"), 0.0, 0.0]}]
    rows = [JournalRow(k, 0.0, 1.0, 1, k, "ok", None, 0, None, None, {"camera_deviation": [good, *bad]}, {}, [],
                       [], None) for k in range(1, 7)]
    section = _health_marks.summarise(rows, 10)
    assert section is not None and section["cycles"] == 6
    (view,) = section["views"]
    assert view["view"] == "S1" and view["n"] == 6 and view["state"] == "repeatability"
    assert view["translation"]["mean"]["d_mm"] == pytest.approx([0.01, 0.0, 0.0])
    assert _health_marks.summarise(rows[:0], 10) is None
