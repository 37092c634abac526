"""The honest grasp target of ``monoguide simulate`` (issue 19, item 6). Prints a table; asserts nothing.

For the simulated roof cell's predicted grasp error (its covariance's principal variances, mm and deg), seeded
runs of N grasps drawn from the prediction (a cell as predicted) and from one 30 % worse, each judged as the
summary judges a job (``daemon/simulate/_grasp_target.py``): the bound of RMS / sigma for N and the share of runs
"met"; beside it the same with the shape unknown (the widest bound, one direction).

    .venv/bin/python benchmarks/bench_grasp_target.py              # 2,000 runs per row (about a minute)
    .venv/bin/python benchmarks/bench_grasp_target.py --trials 500
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from monoguide.daemon.simulate._grasp_target import rms_bound_ratio

sys.path.insert(0, str(Path(__file__).parents[1] / "tests"))  # the helpers the tests share

from helpers.grasp_runs import ROOF_DEG2, ROOF_MM2, met_fraction


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=2000, help="seeded runs per row (default 2000)")
    args = parser.parse_args()
    print(f"{args.trials} seeded runs per row; 'met': RMS of the run's N grasps <= the upper 99 % bound")
    print(f"{'error':<6} {'N':>4} {'bound RMS/sigma':>16} {'as predicted: met':>18} {'30 % worse: not met':>20} "
          f"{'shape unknown: bound, met':>26}")
    for unit, variances in (("mm", ROOF_MM2), ("deg", ROOF_DEG2)):
        for n in (8, 30, 100):
            honest = met_fraction(variances, n, 1.0, seed=n, trials=args.trials)
            worse = 1.0 - met_fraction(variances, n, 1.3, seed=1000 + n, trials=args.trials)
            unknown = met_fraction(variances, n, 1.0, seed=2000 + n, trials=args.trials, shape_known=False)
            print(f"{unit:<6} {n:>4} {rms_bound_ratio(n, variances):>16.3f} {honest:>18.2%} {worse:>20.2%} "
                  f"{rms_bound_ratio(n):>15.3f}, {unknown:>7.2%}")


if __name__ == "__main__":
    main()
