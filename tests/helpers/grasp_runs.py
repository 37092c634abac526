"""Seeded runs of grasp errors drawn from a predicted distribution (or one worse), judged by ``simulate``'s grasp
target (``tests/daemon/simulate/test_grasp_target.py``, ``benchmarks/bench_grasp_target.py``)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from monoguide.daemon.simulate._grasp_target import judge_grasp_errors
from monoguide.solver import frames

# The simulated roof cell's predicted covariance at the grasp point with the robot's repeatability
# (config/sim-cell.toml, f = 0): its principal variances, mm^2 and deg^2 (sigma 0.234 mm, 0.0226 deg).
ROOF_MM2 = (0.008058, 0.023004, 0.023715)
ROOF_DEG2 = (1.3691e-05, 2.3179e-04, 2.6516e-04)


def met_fraction(variances: Sequence[float], n: int, scale: float, seed: int, trials: int = 2000,
                 shape_known: bool = True) -> float:
    """Fraction of ``trials`` seeded runs of ``n`` grasps judged "met": each grasp error a 3-vector of the
    predicted covariance (principal variances ``variances`` in a random frame) times ``scale``; the judge is given
    the prediction (its sigma, and its shape when ``shape_known``)."""
    rng = np.random.default_rng(seed)
    sigma = float(np.sqrt(np.sum(variances)))
    met = 0
    for _ in range(trials):
        R = frames.rotvec_to_matrix(rng.normal(size=3))
        errors = (rng.normal(size=(n, 3)) * np.sqrt(variances) * scale) @ R.T
        met += judge_grasp_errors(np.linalg.norm(errors, axis=1), sigma, variances if shape_known else None).met
    return met / trials
