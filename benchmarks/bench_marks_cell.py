"""Calibration faults with and without fixed reference marks, on the simulated roof cell, cycle by cycle. Prints
tables; asserts nothing.

The cycle's own code in this process (``daemon.cycle.CycleRunner``: the simulated camera's rendering of the holes
and the marks, the hole finder, the solve and its checks, the check job's comparison) on two cells that differ only
in their marks: ``config/sim-cell-marks.toml`` (3 marks per measuring pose) and ``config/sim-cell.toml`` (none).
No transport: the robot is the simulated cell's truth, and it reports the taught pose while it stops with its
repeatability, 0.05 mm / 0.01 deg per axis at the flange (the report does not see it: the issue's accuracy case).
The service believes the marks where a tracker surveyed them: their true centres plus a seeded 0.025 mm per axis.

For each fault (from its first cycle on; the camera bumps about / along each camera axis, the focal changes, a
pose drift of measuring pose 1), ``--cycles`` parts of job 1 (the roof), and one check job:

- with marks: each cycle refused (its code) or ok with its grasp error against the truth (mm at the grasp point);
  the check job (the marks alone, no part): pass or fail;
- without marks: the same cycles, and the check job with the reference part in its nest (``[checks] check_visits``
  visits of the measuring poses, 6 by default).

A cycle "ok" with a grasp error beyond 0.5 mm is a confident wrong answer. ``--accuracy N``: N good cycles with and
without marks and N with a perfect robot: the grasp error RMS with the predicted sigma beside it; the time from the
last frame to the solved and checked pose (the cycle's overhead less the robot's acknowledgment), median, with marks
against without, in this process.

    .venv/bin/python benchmarks/bench_marks_cell.py --cycles 3            # the fault table: ~15 min on 2 cores
    .venv/bin/python benchmarks/bench_marks_cell.py --accuracy 40 --no-faults
"""

from __future__ import annotations

import argparse
import math
import statistics
import threading
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from monoguide.daemon.assembly import build_sim_cell
from monoguide.daemon.config import CellConfig, load_cell_config
from monoguide.daemon.cycle import CycleRunner
from monoguide.daemon.cycle._check import solve_and_check
from monoguide.drivers.sim.calibration_faults import CalibrationFaults
from monoguide.drivers.sim.camera import SimCamera
from monoguide.drivers.sim.cell import SimCell
from monoguide.solver import frames
from monoguide.solver.errors import MonoguideError

REPO = Path(__file__).parents[1]
REQUIREMENT_MM = 0.5
SURVEY_SEED = 11


def faults() -> list[tuple[str, CalibrationFaults]]:
    out = [("no fault", CalibrationFaults())]
    for deg in (0.02, 0.05, 0.1, 0.3, 1.0):
        out += [(f"bump {deg:g} deg about {a}", CalibrationFaults(bump_deg=deg, bump_axis=a)) for a in "xyz"]
    for mm in (0.3, 1.0, 3.0):
        out += [(f"bump {mm:g} mm along {a}", CalibrationFaults(bump_mm=mm, bump_axis=a)) for a in "xyz"]
    out += [(f"focal +{p:g} %", CalibrationFaults(focal_pct=p)) for p in (0.1, 0.5)]
    out.append(("pose 1 drift 0.3 mm 0.05 deg", CalibrationFaults(drift={1: (0.3, 0.05)})))
    return out


class _Robot:
    """The simulated cell's robot: stops with its repeatability, reports the taught pose."""

    def __init__(self, cell: SimCell) -> None:
        self.cell = cell

    def move_to_measuring_pose(self, i: int) -> Any:
        self.cell.move_to_measuring_pose(i)

        @dataclass
        class Status:
            T_b_f: np.ndarray

        return Status(self.cell.T_b_f_taught(i))


@dataclass
class Rig:
    name: str
    config: CellConfig
    cell: SimCell
    camera: SimCamera
    runner: CycleRunner

    def cycle(self, rng: np.random.Generator) -> tuple[str, float | None, float | None, float | None]:
        """(outcome, grasp error mm, predicted sigma mm, seconds from the last frame to the checked pose)."""
        self.cell.new_part(rng)
        try:
            m = self.runner.measure(1, threading.Event(), lambda: RuntimeError("abort"))
            solution = self.runner.solve(m)
            self.runner.check(m, solution)
        except MonoguideError as exc:
            return exc.code, None, None, None
        seconds = time.monotonic() - m.last_frame_at
        T_est = self.config.reference.T_cf_b @ np.array(m.record["T_b_s1"]) @ solution.T_s1_w
        g = self.config.part.grasp_point_w
        g = self.config.part.points_w.mean(axis=0) if g is None else g
        error = float(np.linalg.norm(frames.transform_points(T_est, g[None])
                                     - frames.transform_points(self.cell.T_cf_w_true, g[None])))
        return "ok", error, float(solution.quality[1]), seconds

    def check(self) -> str:
        self.cell.reference_part()
        try:
            holes = not self.runner.has_marks
            visits = [self.runner.measure(1, threading.Event(), lambda: RuntimeError("abort"), holes)
                      for _ in range(self.runner.checks.check_visits if holes else 1)]
            solve_and_check(self.runner, *visits)
        except MonoguideError as exc:
            return f"fail ({exc.code})"
        return "pass"


def rig(name: str, path: Path, *, perfect: bool = False, seed: int = 5) -> Rig:
    truth = load_cell_config(path).for_job(1)
    cell = build_sim_cell(truth)
    if perfect:
        cell.spec = replace(cell.spec, repeatability_mm=0.0, repeatability_deg=0.0)
    cell.rng = np.random.default_rng(seed)
    survey = np.random.default_rng(SURVEY_SEED)
    marks = tuple(replace(m, position_cf=m.position_cf + survey.normal(0.0, m.sigma_mm, 3))
                  for m in truth.reference_marks)
    believed = replace(truth, reference_marks=marks)
    camera = SimCamera(cell, seed=seed)
    camera.open()
    return Rig(name, believed, cell, camera, CycleRunner(believed, camera, _Robot(cell)))


def fault_table(rigs: list[Rig], cycles: int, seed: int) -> None:
    print(f"\nfaults: {cycles} roof cycles each, then one check job; seed {seed}")
    header = f"{'fault':32s} | " + " | ".join(f"{r.name + ': ok / refused (codes)':44s} | {'ok > 0.5 mm':11s} | "
                                              f"{'max ok mm':9s} | {'check':24s}" for r in rigs)
    print(header)
    print("-" * len(header))
    totals = {r.name: 0 for r in rigs}
    for name, fault in faults():
        cells = []
        for r in rigs:
            r.camera.set_calibration_faults(fault)
            rng = np.random.default_rng(seed)
            results = [r.cycle(rng) for _ in range(cycles)]
            ok = [e for code, e, _, _ in results if code == "ok" and e is not None]
            codes = sorted({code for code, *_ in results if code != "ok"})
            wrong = sum(e > REQUIREMENT_MM for e in ok)
            totals[r.name] += wrong
            check = r.check()
            cells.append(f"{f'{len(ok)} / {cycles - len(ok)} ' + (','.join(codes) if codes else ''):44s} | "
                         f"{wrong:11d} | {max(ok) if ok else float('nan'):9.3f} | {check:24s}")
        print(f"{name:32s} | " + " | ".join(cells), flush=True)
        for r in rigs:
            r.camera.set_calibration_faults(CalibrationFaults())
    print("cycles ok beyond 0.5 mm in all: " + ", ".join(f"{k} {v}" for k, v in totals.items()))


def accuracy_table(paths: dict[str, Path], n: int, seed: int) -> None:
    print(f"\naccuracy: {n} good roof cycles each, seed {seed}; the robot's repeatability 0.05 mm / 0.01 deg unseen by "
          "its report")
    print(f"{'cell':34s} | {'grasp RMS mm':12s} | {'max mm':7s} | {'predicted sigma mm':18s} | "
          f"{'last frame -> checked pose, median ms':38s} | refused")
    medians = {}
    for name, path, perfect in [(f"{k}", p, False) for k, p in paths.items()] + [
            (f"{k}, perfect robot", p, True) for k, p in paths.items()]:
        r = rig(name, path, perfect=perfect, seed=seed)
        rng = np.random.default_rng(seed)
        results = [r.cycle(rng) for _ in range(n)]
        errors = [e for code, e, _, _ in results if code == "ok" and e is not None]
        sigmas = [s for code, _, s, _ in results if code == "ok" and s is not None]
        seconds = [t for code, _, _, t in results if code == "ok" and t is not None]
        refused = [code for code, *_ in results if code != "ok"]
        rms = math.sqrt(sum(e * e for e in errors) / len(errors)) if errors else float("nan")
        med = 1e3 * statistics.median(seconds) if seconds else float("nan")
        medians[name] = med
        print(f"{name:34s} | {rms:12.4f} | {max(errors) if errors else float('nan'):7.4f} | "
              f"{statistics.median(sigmas) if sigmas else float('nan'):18.4f} | {med:38.1f} | "
              f"{len(refused)} {sorted(set(refused))}", flush=True)
        r.runner.close()
    names = list(paths)
    if len(names) == 2 and medians.get(names[1]):
        print(f"overhead ratio {names[0]} / {names[1]}: {medians[names[0]] / medians[names[1]]:.2f} (same process)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cycles", type=int, default=3, help="cycles under each fault (default 3)")
    parser.add_argument("--seed", type=int, default=5)
    parser.add_argument("--accuracy", type=int, default=0, help="also N good cycles with and without marks")
    parser.add_argument("--no-faults", action="store_true", help="skip the fault table")
    parser.add_argument("--cells", choices=("both", "with", "without"), default="both",
                        help="the fault table of both cells (default), or of the one with or without marks")
    args = parser.parse_args()
    paths = {"with marks": REPO / "config/sim-cell-marks.toml", "without marks": REPO / "config/sim-cell.toml"}
    if args.accuracy:
        accuracy_table(paths, args.accuracy, args.seed)
    if not args.no_faults:
        rigs = [rig(name, path, seed=args.seed) for name, path in paths.items()
                if args.cells == "both" or name == f"{args.cells} marks"]
        fault_table(rigs, args.cycles, args.seed)
        for r in rigs:
            r.runner.close()


if __name__ == "__main__":
    main()
