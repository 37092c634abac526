"""One solve's evidence on the calibration, as the trend monitor takes it (light: no solver import)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Residual:
    """The squared whitened residual of a solve, its degrees of freedom and each view's share (``solver.trend``);
    a solve the consistency test refused carries it on its exception (``exc.residual``)."""

    chi2: float
    dof: int
    per_view: tuple[tuple[float, int], ...] = ()
