"""``[service]`` and ``[checks]``: what ``monoguide run`` keeps of each cycle, and what a cycle's result must pass
before its offset goes to the robot (docs/service.md, docs/cycle.md)."""

from __future__ import annotations

from dataclasses import dataclass

from monoguide.daemon.config._bounds import bounded_integer, bounded_number
from monoguide.daemon.config._reader import ConfigTable
from monoguide.drivers.errors import ConfigError
from monoguide.solver.envelope import DeviationEnvelope


@dataclass(frozen=True)
class ServiceConfig:
    """``[service]``: what ``monoguide run`` keeps of each cycle (docs/service.md)."""

    keep_images: bool = True  # write each cycle's camera images under <state dir>/images/cycle-<n>/
    images_max_mb: float = 2000.0  # the oldest cycles' images are deleted beyond this total size
    images_max_age_days: float = 30.0  # ... and beyond this age (the journal rows are kept)


def read_service(t: ConfigTable) -> ServiceConfig:
    out = ServiceConfig(
        keep_images=t.boolean("keep_images", True),
        images_max_mb=bounded_number(t, "images_max_mb", 2000.0),
        images_max_age_days=bounded_number(t, "images_max_age_days", 30.0),
    )
    t.done()
    return out


@dataclass(frozen=True)
class ChecksConfig:
    """``[checks]``: what a cycle's result must pass before its offset goes to the robot (docs/cycle.md).
    ``None`` envelope keys: from ``[layout]`` (its per-axis envelope, the totals their norms), else the
    default envelope (+-50 mm, +-5 deg per axis, the totals their norms): :meth:`envelope`."""

    max_rms_px: float = 1.0  # reprojection RMS above this: RESIDUAL_TOO_LARGE
    max_sigma_mm: float = 0.5  # predicted sigma of the grasp point above this: UNCERTAINTY_TOO_LARGE
    max_sigma_deg: float = 0.1  # predicted sigma of the rotation above this: UNCERTAINTY_TOO_LARGE
    false_alarm_rate: float = 1e-3  # the consistency test's (INCONSISTENT_MEASUREMENT)
    marks_false_alarm_rate: float = 1e-4  # the reference marks' tolerance, per cycle (CALIBRATION_SUSPECT)
    check_visits: int = 6  # visits of the measuring poses by the check job of a cell without marks
    envelope_mm: float | None = None  # the grasp point's shift in total, mm
    envelope_deg: float | None = None  # the rotation angle, deg
    envelope_axis_mm: tuple[float, float, float] | None = None  # per axis of the reference part frame
    envelope_axis_deg: tuple[float, float, float] | None = None

    def envelope(self, planned: DeviationEnvelope | None) -> DeviationEnvelope:
        """The part's one envelope, which the offset check holds it to: ``planned`` (its ``[layout]`` envelope:
        per axis and its point; None: +-50 mm / +-5 deg about the holes' centroid) with the per-axis limits and
        the totals these keys set (totals not set: the norms of the per-axis limits)."""
        base = planned if planned is not None else DeviationEnvelope()
        return DeviationEnvelope(self.envelope_axis_mm or base.translation_mm,
                                 self.envelope_axis_deg or base.rotation_deg, base.about_w,
                                 self.envelope_mm if self.envelope_mm is not None else base.total_mm,
                                 self.envelope_deg if self.envelope_deg is not None else base.total_deg)


def read_checks(t: ConfigTable) -> ChecksConfig:
    axis_mm, axis_deg = t.vector("envelope_axis_mm", 3, None), t.vector("envelope_axis_deg", 3, None)
    for key, value in (("envelope_axis_mm", axis_mm), ("envelope_axis_deg", axis_deg)):
        if value is not None and min(value) <= 0:
            raise ConfigError(f"{t.where}.{key} = {[float(v) for v in value]}: expected 3 limits > 0")
    rate = t.number("false_alarm_rate", 1e-3, positive=True)
    if rate >= 1.0:
        raise ConfigError(f"{t.where}.false_alarm_rate = {rate}: must lie between 0 and 1")
    marks_rate = t.number("marks_false_alarm_rate", 1e-4, positive=True)
    if marks_rate >= 1.0:
        raise ConfigError(f"{t.where}.marks_false_alarm_rate = {marks_rate}: must lie between 0 and 1")
    out = ChecksConfig(
        max_rms_px=t.number("max_rms_px", 1.0, positive=True),
        max_sigma_mm=t.number("max_sigma_mm", 0.5, positive=True),
        max_sigma_deg=t.number("max_sigma_deg", 0.1, positive=True),
        false_alarm_rate=rate,
        marks_false_alarm_rate=marks_rate,
        check_visits=bounded_integer(t, "check_visits", 6),
        envelope_mm=t.number("envelope_mm", None, positive=True),
        envelope_deg=t.number("envelope_deg", None, positive=True),
        envelope_axis_mm=None if axis_mm is None else tuple(float(v) for v in axis_mm),
        envelope_axis_deg=None if axis_deg is None else tuple(float(v) for v in axis_deg),
    )
    t.done()
    return out
