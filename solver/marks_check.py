"""The checks of a fit with fixed marks: a camera that stood elsewhere, a mark that is not where it was surveyed.

Each block of the model is tested alone by its generalised likelihood ratio (:func:`block_tests`): freeing the
block, how much does the whitened residual drop? For a good measurement the drop is chi-square with as many degrees
of freedom as the block has measured directions. A view's camera block is the Mahalanobis distance of its estimated
correction against the scatter a good camera gives it; the cameras block is every checked view's together (a move
common to the views, as of the camera on its bracket, adds up over them); a mark's block is its survey against what
the rest sees.

The marks' tolerance is a per-cycle false-alarm rate (default 1e-4), split evenly (Bonferroni) over the checked
views, the cameras block and the marks: a good cycle is refused by it at most that often. The tolerance printed in
mm / deg is where the test's boundary lies along the direction of the observed deviation. The whole fit's
chi-square (the rate of :mod:`solver.consistency`, 1e-3 by default) is tested as well. The block that explains a
misfit best (the smallest chance under a good measurement) names the refusal: a calibration block beyond its own
threshold -> :class:`CalibrationSuspect` (the mark, or the views); else :class:`InconsistentMeasurement`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.stats

from monoguide.solver.consistency import AMBIGUOUS_RATIO, DEFAULT_FALSE_ALARM_RATE, Consistency, chi2_threshold
from monoguide.solver.errors import CalibrationSuspect, InconsistentMeasurement, MonoguideError
from monoguide.solver.marks import MEASURED_SHARE, MarksProblem, MarksResult, fit_marks
from monoguide.solver.pose import PoseResult

DEFAULT_MARKS_FALSE_ALARM_RATE = 1e-4  # per cycle: the marks' tolerance (every view, the views together, every mark)


@dataclass(frozen=True)
class BlockTest:
    """One block's test: ``kind`` view | cameras (every checked view's together) | mark | hole, its ``index`` (view,
    -1, mark, hole observation), the statistic with its measured directions ``dof``, the ``threshold`` it is held
    against (None: only used to name a misfit), and the estimated error in whitened units along the block's rows."""

    kind: str
    index: int
    name: str
    statistic: float
    dof: int
    threshold: float | None
    error: np.ndarray

    @property
    def exceeded(self) -> bool:
        return self.threshold is not None and self.statistic > self.threshold

    @property
    def log_chance(self) -> float:
        """log P(chi-square > statistic) under a good measurement: the smaller, the better it explains a misfit."""
        return float(scipy.stats.chi2.logsf(self.statistic, self.dof)) if self.dof > 0 else 0.0


@dataclass(frozen=True)
class MarksAssessment:
    """All block tests of one fit, the whole fit's chi-square test, and the refusal (None: the cycle may go on)."""

    tests: tuple[BlockTest, ...]
    block_false_alarm_rate: float
    consistency: Consistency
    refusal: MonoguideError | None

    def test(self, kind: str, index: int) -> BlockTest | None:
        return next((t for t in self.tests if t.kind == kind and t.index == index), None)


def solve_with_marks(
    problem: MarksProblem,
    *,
    false_alarm_rate: float = DEFAULT_MARKS_FALSE_ALARM_RATE,
    consistency_false_alarm_rate: float = DEFAULT_FALSE_ALARM_RATE,
    T_init: np.ndarray | None = None,
) -> MarksResult:
    """Fit (:func:`solver.marks.fit_marks`, from ``T_init`` when given), check (:func:`assess_marks`) and return the
    result with its assessment; raises :class:`CalibrationSuspect` (a view's camera, a mark) or
    :class:`InconsistentMeasurement`."""
    result = fit_marks(problem, T_init)
    result.assessment = assess_marks(result, false_alarm_rate, consistency_false_alarm_rate)
    if result.assessment.refusal is not None:
        raise result.assessment.refusal
    return result


def assess_marks(
    result: MarksResult,
    false_alarm_rate: float = DEFAULT_MARKS_FALSE_ALARM_RATE,
    consistency_false_alarm_rate: float = DEFAULT_FALSE_ALARM_RATE,
) -> MarksAssessment:
    """The block tests at ``false_alarm_rate`` per cycle and the whole fit's test, and what they refuse."""
    for name, rate in (("false_alarm_rate", false_alarm_rate), ("consistency_false_alarm_rate",
                                                                consistency_false_alarm_rate)):
        if not 0.0 < rate < 1.0:
            raise ValueError(f"{name} must lie in (0, 1), got {rate!r}")
    raw = block_tests(result)
    checked = [b for b in raw if b[0] != "hole" and b[3] > 0]
    per_block = false_alarm_rate / max(len(checked), 1)
    problem = result.problem
    tests = []
    for kind, index, statistic, dof, error in raw:
        threshold = chi2_threshold(dof, per_block) if kind != "hole" and dof > 0 else None
        tests.append(BlockTest(kind, index, _block_name(problem, kind, index), statistic, dof, threshold, error))
    fit_threshold = chi2_threshold(result.dof, consistency_false_alarm_rate) if result.dof > 0 else None
    consistency = Consistency(result.chi2, result.dof, fit_threshold)
    return MarksAssessment(tuple(tests), per_block, consistency, _refusal(result, tests, consistency, per_block))


def block_tests(result: MarksResult) -> list[tuple[str, int, float, int, np.ndarray]]:
    """(kind, index, statistic, measured directions, estimated error in whitened units) of every block.

    At the solution the whitened residual ``z`` is orthogonal to the Jacobian's columns; a block's rows keep the
    share ``M = I - B B^T`` of their own variance (``B`` those rows of an orthonormal basis of the columns). Over
    M's eigen-directions with more than ``MEASURED_SHARE`` kept, the statistic is ``sum (v.z)^2 / lambda``.
    """
    basis, _ = np.linalg.qr(result.Jw)
    residual = result.z - basis @ (basis.T @ result.z)
    out = []
    for kind, index, rows in result.blocks:
        B = basis[rows]
        lam, V = np.linalg.eigh(np.eye(len(rows)) - B @ B.T)
        keep = lam > MEASURED_SHARE
        c = V[:, keep].T @ residual[rows]
        out.append((kind, index, float(np.sum(c**2 / lam[keep])), int(np.sum(keep)), V[:, keep] @ (c / lam[keep])))
    return out


def as_pose_result(result: MarksResult) -> PoseResult:
    """The fit as today's :class:`PoseResult` (hole residuals observed minus predicted, px), for the cycle."""
    h = result.problem.holes
    residuals = -result.z[: 2 * h.n_observations].reshape(-1, 2) * h.sigma_px
    consistency = result.assessment.consistency if result.assessment is not None else None
    return PoseResult(result.T_s1_w, result.covariance, residuals, result.iterations, "ml-marks", consistency)


# --- refusals -----------------------------------------------------------------------------------


def _refusal(result: MarksResult, tests: list[BlockTest], consistency: Consistency, per_block: float
             ) -> MonoguideError | None:
    misfit = consistency.threshold is not None and consistency.chi2 > consistency.threshold
    flagged = [t for t in tests if t.exceeded]
    if not flagged and not misfit:
        return None
    candidates = [t for t in tests if t.dof > 0]
    best = min(candidates, key=lambda t: t.log_chance) if candidates else None
    fit = f"chi-square of the whole fit {consistency.chi2:.4g} on {consistency.dof} degrees of freedom"
    if consistency.threshold is not None:
        fit += f", threshold {consistency.threshold:.4g}"
    if flagged and (best is None or best.kind != "hole"):  # the tolerance: a calibration block beyond its own
        marks = [t for t in flagged if t.kind == "mark"]
        views = [t for t in flagged if t.kind == "view"]
        joint = [t for t in flagged if t.kind == "cameras"]
        best_is_mark = any(t is best for t in marks)
        if best_is_mark or not (views or joint):
            mark = best if best_is_mark else min(marks, key=lambda t: t.log_chance)
            return CalibrationSuspect(_mark_message(result, mark) + f"; {fit}. Nothing is written to the robot.")
        if views:
            text = "; ".join(_view_message(result, t, per_block) for t in views)
        else:
            text = _joint_message(result, joint[0], per_block)
        return CalibrationSuspect(
            f"{text}. Each view's marks agree with each other and with the holes: the camera moved (its bracket, "
            "the lens) or the measuring pose is not where it was calibrated; run the check job or recalibrate. "
            "Nothing is written to the robot.")
    ranked = sorted(candidates, key=lambda t: t.log_chance)
    if not ranked:
        where = "no single observation explains it"
    elif len(ranked) > 1 and ranked[1].log_chance <= AMBIGUOUS_RATIO * ranked[0].log_chance:
        where = (f"{ranked[0].name} explains most of it, {ranked[1].name} nearly as well (the measurement cannot "
                 "tell which)")
    else:
        where = f"{ranked[0].name} explains most of it"
    return InconsistentMeasurement(
        f"the fit with marks does not match the stated noise ({fit}); {where}: check that centre, that mark or "
        "that view's calibration. Nothing is written to the robot.")


def view_deviation(result: MarksResult, test: BlockTest) -> list[tuple[int, float, float]]:
    """(view, mm, deg) of each camera of a view block (one) or of the cameras block (every checked view) from its
    calibrated pose as the marks measure it: the block's estimated error (the prior left out, over the measured
    directions), not the fit's correction, which the prior shrinks."""
    views = [test.index] if test.kind == "view" else [v for v, ok in enumerate(result.problem.checked) if ok]
    F = result.problem.prior_factor()
    out = []
    for j, view in enumerate(views):
        e = F @ test.error[6 * j : 6 * j + 6]
        out.append((view, float(np.linalg.norm(e[3:])), math.degrees(float(np.linalg.norm(e[:3])))))
    return out


def view_tolerance(result: MarksResult, test: BlockTest) -> np.ndarray:
    """(6,) how far the camera may stand along each of its axes alone before the view's test refuses: rotation
    about x, y, z (deg) and shift along x, y, z (mm); inf along an axis the marks do not measure."""
    L = np.linalg.inv(result.problem.prior_factor())
    basis, _ = np.linalg.qr(result.Jw)
    rows = next(r for kind, index, r in result.blocks if kind == test.kind and index == test.index)
    B = basis[rows]
    lam, V = np.linalg.eigh(np.eye(len(rows)) - B @ B.T)
    keep = lam > MEASURED_SHARE
    W = V[:, keep] * np.sqrt(lam[keep])  # stat(e) = |W^T L e|^2 for a deviation e (the block's estimate)
    per_unit = np.sum((W.T @ L) ** 2, axis=0)
    with np.errstate(divide="ignore"):
        tolerance = np.sqrt((test.threshold or np.inf) / per_unit)
    tolerance[:3] = np.degrees(tolerance[:3])
    return tolerance


def _view_message(result: MarksResult, test: BlockTest, per_block: float) -> str:
    camera = result.cameras[test.index]
    [(_, mm, deg)] = view_deviation(result, test)
    scale = math.sqrt(test.threshold / test.statistic) if test.threshold and test.statistic > 0 else float("nan")
    return (f"view {camera.view}: the camera stood {mm:.2f} mm / {deg:.3f} deg from its calibrated pose "
            f"(tolerance {scale * mm:.2f} mm / {scale * deg:.3f} deg in that direction: Mahalanobis "
            f"distance {math.sqrt(test.statistic):.1f} > {math.sqrt(test.threshold or 0.0):.1f} over {test.dof} "
            f"measured directions, false-alarm rate {per_block:.2g} per view)")


def _joint_message(result: MarksResult, test: BlockTest, per_block: float) -> str:
    scale = math.sqrt(test.threshold / test.statistic) if test.threshold and test.statistic > 0 else float("nan")
    deviations = view_deviation(result, test)
    names = ", ".join(result.cameras[v].view for v, _, _ in deviations)
    stood = ", ".join(f"{mm:.2f} mm / {deg:.3f} deg" for _, mm, deg in deviations)
    tolerance = ", ".join(f"{scale * mm:.2f} mm / {scale * deg:.3f} deg" for _, mm, deg in deviations)
    return (f"views {names} together: the cameras stood {stood} from their calibrated poses, a move common to the "
            f"views (tolerance {tolerance} in that direction: Mahalanobis distance {math.sqrt(test.statistic):.1f} > "
            f"{math.sqrt(test.threshold or 0.0):.1f} over {test.dof} measured directions, false-alarm rate "
            f"{per_block:.2g}; no view alone is beyond its own)")


def _mark_message(result: MarksResult, test: BlockTest) -> str:
    problem = result.problem
    mark = problem.marks[test.index]
    views = sorted({problem.view_names[v] for v, m in zip(problem.mark_view, problem.mark_index, strict=True)
                    if m == test.index})
    off_mm = float(np.linalg.norm(test.error)) * mark.sigma_mm
    threshold = f" > {test.threshold:.3g}" if test.threshold is not None else ""
    return (f"mark {mark.name} (seen by view {', '.join(views)}) disagrees with the other marks and the holes: it "
            f"appears {off_mm:.2f} mm from its surveyed position (survey sigma {mark.sigma_mm:g} mm; statistic "
            f"{test.statistic:.4g}{threshold} on {test.dof} degrees of freedom): re-survey it or check that nothing "
            "moved or hides it")


def _block_name(problem: MarksProblem, kind: str, index: int) -> str:
    if kind == "cameras":
        return "the cameras of views " + ", ".join(n for n, ok in zip(problem.view_names, problem.checked,
                                                                      strict=True) if ok) + " together"
    if kind == "view":
        return f"view {problem.view_names[index]}"
    if kind == "mark":
        return f"mark {problem.marks[index].name}"
    h = problem.holes
    return f"hole {int(h.point_index[index])} in view {problem.view_names[int(h.view_index[index])]}"
