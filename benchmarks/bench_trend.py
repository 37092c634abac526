"""The trend monitor against calibration faults. Prints tables; asserts nothing.

Solver-level Monte Carlo over the paper's roof cell (``solver.synthetic.paper_roof_cell``: four views straight down
from 650 mm, one hole each, 2 degrees of freedom per cycle), parts drawn in +-5 deg / +-50 mm, 0.1 px centre noise
and the robot's repeatability 0.05 mm / 0.01 deg per axis at every view (drawn every cycle, modelled by the solver's
``view_sigma``). Each cycle is solved by the ML estimator with the calibrated model; its chi-square goes to the
per-cycle check (``solver.consistency`` at its default false-alarm rate) and to the monitor (``solver.trend``).

(a) good cycles: the monitor's alarms (each alarm counted, then the monitor reset as a recalibration would) and
    warning episodes (from a rise above the warning level until the statistic is back at 0) per 10,000 cycles.
(b) per calibration fault (``solver.calibration_faults``), seeded runs from the fault on (the monitor reset when
    the fault happens): the grasp error (the holes' centroid, RMS over every cycle), the share the per-cycle check
    refuses, the monitor's detection delay (cycles from the fault to the alarm, median and 90th percentile; runs
    without an alarm by --max-cycles count as beyond it), and the cycles reported "ok" with a grasp error beyond
    0.5 mm before the alarm (median, 90th percentile per run; "+": that run ended without an alarm, so the count
    goes on; a good cell has some 2.5 % of its cycles beyond 0.5 mm, the robot's repeatability). "delta" is the
    fault's non-centrality of the chi-square: its mean minus the good cell's (the first row) on the same seeded
    draws (common random numbers: every fault sees the same parts and noise). "Markov" is the delay the monitor's
    Markov chain predicts for that delta; "any >="
    is Lorden's asymptotic bound for *any* detector of a constant bias of that size in the residual at the same
    ARL0, even one that knew its direction: 2 ln(ARL0) / delta cycles (the residual's Kullback-Leibler
    information per cycle is delta / 2).

    .venv/bin/python benchmarks/bench_trend.py                # 10-20 minutes on two cores
    .venv/bin/python benchmarks/bench_trend.py --cycles 2000 --runs 5 --max-cycles 200   # a quick look
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass

import numpy as np
import scipy.stats

from monoguide.solver import frames
from monoguide.solver.calibration_faults import (
    AXES,
    CalibrationFault,
    camera_bump,
    faulty_pixels,
    focal_change,
    pose_drift,
)
from monoguide.solver.consistency import DEFAULT_FALSE_ALARM_RATE, chi2_threshold
from monoguide.solver.errors import MonoguideError
from monoguide.solver.pose import solve_ml
from monoguide.solver.synthetic import deviated_part, paper_roof_cell
from monoguide.solver.trend import (
    ALARM_ARL0,
    SERVICE_ALARM_ARL0,
    WARNING_ARL0,
    TrendMonitor,
    average_run_length,
    residual_chi2,
)

ALARM_USED: float = ALARM_ARL0

CELL = paper_roof_cell()
GRASP_W = CELL.points_w.mean(axis=0)  # the roof has no grasp point of its own: the holes' centroid
SIGMA_PX, REP_MM, REP_DEG = 0.1, 0.05, 0.01
NEEDED_MM = 0.5
DOF = 2 * len(CELL.observed) - 6
REFUSED = chi2_threshold(DOF, DEFAULT_FALSE_ALARM_RATE)


@dataclass(frozen=True)
class Cycle:
    """One simulated cycle: its chi-square, whether the per-cycle check refused it, its grasp error (mm)."""

    chi2: float
    refused: bool
    grasp_mm: float


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cycles", type=int, default=20_000, help="good cycles for the false alarms (20,000)")
    parser.add_argument("--runs", type=int, default=20, help="seeded runs per fault (20)")
    parser.add_argument("--max-cycles", type=int, default=1000, help="cycles per run before giving up (1000)")
    parser.add_argument("--seed", type=int, default=2020, help="seed (2020)")
    parser.add_argument("--jobs", type=int, default=2, help="worker processes (2)")
    parser.add_argument("--alarm-arl0", type=float, default=ALARM_ARL0,
                        help=f"the alarm level's nominal ARL0 ({ALARM_ARL0:,}; the service's: {SERVICE_ALARM_ARL0:,})")
    args = parser.parse_args()
    global ALARM_USED
    ALARM_USED = args.alarm_arl0  # the forked workers inherit it
    print("$ .venv/bin/python benchmarks/bench_trend.py " + " ".join(sys.argv[1:]))
    monitor = TrendMonitor(DOF, alarm_arl0=ALARM_USED)
    levels = monitor.levels
    print(f"solver-level Monte Carlo, the paper's roof cell (4 views, 1 hole each, dof {DOF}), parts +-5 deg / "
          f"+-50 mm, {SIGMA_PX} px, repeatability {REP_MM} mm / {REP_DEG} deg per view; seed {args.seed}")
    print(f"monitor: CUSUM of chi2 scaled by {levels.scale:g}; warning level {levels.warning:.3f} (ARL0 "
          f"{WARNING_ARL0:,}), alarm level {levels.alarm:.3f} (nominal ARL0 {ALARM_USED:,.0f}); per-cycle check: "
          f"chi2 > {REFUSED:.2f} (false-alarm rate {DEFAULT_FALSE_ALARM_RATE:g})")
    print()
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        _false_alarms(pool, args)
        print()
        _faults(pool, args)


def fault_list() -> list[CalibrationFault]:
    """No fault (for reference), then the issue's: camera bumps about and along each camera axis, focal, pose drift."""
    faults = [CalibrationFault("none (a good cell)")]
    faults += [camera_bump(axis, deg=deg) for deg in (0.02, 0.05, 0.1, 0.3, 1.0) for axis in AXES]
    faults += [camera_bump(axis, mm=mm) for mm in (0.3, 1.0, 3.0) for axis in AXES]
    faults += [focal_change(0.1), focal_change(0.5)]
    faults += [pose_drift(1, axis, mm=0.3, deg=0.05) for axis in AXES]
    return faults


def simulate(fault: CalibrationFault, rng: np.random.Generator) -> Cycle:
    """One cycle of the cell with ``fault``, solved with the calibrated model."""
    T_true = deviated_part(CELL, rng, 5.0, 50.0)
    problem = CELL.problem(faulty_pixels(CELL, fault, T_true, rng, SIGMA_PX, REP_MM, REP_DEG), SIGMA_PX, REP_MM,
                           REP_DEG)
    T_est = solve_ml(problem).T_s1_w
    chi2, _ = residual_chi2(problem, T_est)
    g_est, g_true = (frames.transform_points(T, GRASP_W[None])[0] for T in (T_est, T_true))
    return Cycle(chi2, chi2 > REFUSED, float(np.linalg.norm(g_est - g_true)))


def _false_alarms(pool: ProcessPoolExecutor, args: argparse.Namespace) -> None:
    chunks = [(args.seed, k, n) for k, n in enumerate(_split(args.cycles, 20))]
    results = list(pool.map(_good_chunk, chunks))
    chi2 = np.concatenate(results)
    monitor = TrendMonitor(DOF, alarm_arl0=ALARM_USED)
    alarms = warnings = 0
    in_episode = False  # a warning episode: from the rise above the level until the statistic is back at 0
    for x in chi2:
        reading = monitor.update(float(x), DOF)
        if reading.warning and not in_episode:
            warnings += 1
            in_episode = True
        elif reading.statistic == 0.0:
            in_episode = False
        if reading.alarm:
            alarms += 1
            monitor.reset()
            in_episode = False
    n = len(chi2)
    print(f"(a) {n:,} good cycles (solver-level Monte Carlo): mean chi2 {chi2.mean():.3f} (dof {DOF}), refused by "
          f"the per-cycle check {np.sum(chi2 > REFUSED)} ({1e4 * np.mean(chi2 > REFUSED):.1f} per 10,000)")
    print(f"{'':4}{'level':<10} {'target per 10,000':>18} {'counted':>8} {'per 10,000':>11} {'95 % upper':>11}")
    for name, count, target in (("warning", warnings, WARNING_ARL0), ("alarm", alarms, ALARM_ARL0)):  # the targets
        print(f"{'':4}{name:<10} {f'<= {1e4 / target:g}':>18} {count:>8} {1e4 * count / n:>11.2f} "
              f"{1e4 * _poisson_upper(count) / n:>11.2f}")


def _good_chunk(job: tuple[int, int, int]) -> np.ndarray:
    seed, k, n = job
    rng = np.random.default_rng([seed, 0, k])
    none = CalibrationFault()
    out = []
    for _ in range(n):
        try:
            out.append(simulate(none, rng).chi2)
        except MonoguideError:  # a solve that fails gives the monitor nothing (none seen in this cell)
            continue
    return np.array(out)


def _faults(pool: ProcessPoolExecutor, args: argparse.Namespace) -> None:
    faults = fault_list()
    jobs = [(args.seed, i, run, args.max_cycles) for i in range(len(faults)) for run in range(args.runs)]
    runs = list(pool.map(_fault_run, jobs, chunksize=max(1, args.runs // 4)))
    cap = args.max_cycles
    print(f"(b) {args.runs} seeded runs per fault, each from the fault until the alarm (at most {cap} cycles); "
          f"common random numbers across faults")
    header = (f"{'fault':<34} {'grasp RMS mm':>12} {'refused':>8} {'delta':>6} {'alarmed':>8} {'delay median':>12} "
              f"{'p90':>6} {'Markov':>7} {'any >=':>7} {'ok > 0.5 mm: median':>20} {'p90':>5}  note")
    print(header)
    print("-" * len(header))
    good_mean = None
    for i, fault in enumerate(faults):
        mine = runs[i * args.runs : (i + 1) * args.runs]
        cycles = [c for run_cycles, _ in mine for c in run_cycles]
        delays = [d for _, d in mine]
        grasp = math.sqrt(statistics.fmean(c.grasp_mm**2 for c in cycles))
        refused = statistics.fmean(c.refused for c in cycles)
        mean = statistics.fmean(c.chi2 for c in cycles)
        good_mean = mean if good_mean is None else good_mean  # the first row, no fault: the same seeded draws
        delta = max(0.0, mean - good_mean)
        bad_ok = sorted((sum(not c.refused and c.grasp_mm > NEEDED_MM for c in run_cycles), d is None)
                        for run_cycles, d in mine)
        alarmed = sum(d is not None for d in delays)
        ranked = sorted(cap + 1 if d is None else d for d in delays)
        markov = average_run_length(TrendMonitor(DOF, alarm_arl0=ALARM_USED).levels.alarm, DOF, noncentrality=delta)
        bound = 2.0 * math.log(ALARM_USED) / delta if delta > 0 else math.inf
        note = _note(grasp, refused, alarmed, len(delays), delta)
        print(f"{fault.name:<34} {grasp:>12.3f} {refused:>8.1%} {delta:>6.2f} {alarmed:>3}/{len(delays):<4} "
              f"{_cycles(_quantile(ranked, 0.5), cap):>12} {_cycles(_quantile(ranked, 0.9), cap):>6} "
              f"{_cycles(markov, cap):>7} {_cycles(bound, cap):>7} {_counted(bad_ok, 0.5):>20} "
              f"{_counted(bad_ok, 0.9):>5}  {note}")


def _fault_run(job: tuple[int, int, int, int]) -> tuple[list[Cycle], int | None]:
    """One run of fault ``i``: cycles until the alarm or ``cap``; the delay (cycles) or None."""
    seed, i, run, cap = job
    fault = fault_list()[i]
    rng = np.random.default_rng([seed, 1, run])  # the same parts and noise for every fault
    monitor = TrendMonitor(DOF, alarm_arl0=ALARM_USED)
    cycles = []
    for _ in range(cap):
        try:
            cycle = simulate(fault, rng)
        except MonoguideError:
            continue
        cycles.append(cycle)
        if monitor.update(cycle.chi2, DOF).alarm:
            return cycles, len(cycles)
    return cycles, None


def _note(grasp: float, refused: float, alarmed: int, runs: int, delta: float) -> str:
    if grasp <= NEEDED_MM:
        return "RMS within 0.5 mm"
    if refused > 0.9:
        return "refused by the per-cycle check"
    if delta < 0.05:
        return "UNDETECTABLE by residuals: to the solver, a moved part"
    if alarmed == 0:
        return "not detected (too little residual)"
    if alarmed < runs:
        return f"missed in {runs - alarmed} run(s)"
    return ""


def _counted(ranked: list[tuple[int, bool]], q: float) -> str:
    """The q-quantile of per-run counts; '+' when that run ended without an alarm (the count goes on)."""
    count, censored = ranked[min(len(ranked) - 1, max(0, math.ceil(q * len(ranked)) - 1))]
    return f"{count}+" if censored else f"{count}"


def _cycles(value: float, cap: int) -> str:
    return f">{cap}" if value > cap else f"{value:.0f}"


def _quantile(ranked: list[float], q: float) -> float:
    return float(np.quantile(np.asarray(ranked, dtype=float), q, method="inverted_cdf"))


def _poisson_upper(count: int) -> float:
    """The one-sided 95 % upper bound of a Poisson mean after ``count`` events."""
    return float(scipy.stats.chi2.ppf(0.95, 2 * count + 2) / 2)


def _split(total: int, parts: int) -> list[int]:
    return [total // parts + (k < total % parts) for k in range(parts)]


if __name__ == "__main__":
    main()
