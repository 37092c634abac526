"""The one error hierarchy of monoguide, rooted in :class:`MonoguideError`.

Every failure a user must tell apart is a subclass with a stable string ``code`` (logs, JSON, journal)
and a stable integer ``plc_code`` (the PLC's error register). The root lives in the solver because the
solver is the bottom layer: drivers and daemon derive their own failures from it.

Ranges of ``plc_code``: 1xx measurement record, 2xx pose solve, 3xx hole detection, 4xx devices,
5xx config and offset checks, 6xx cycle.
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable


class MonoguideError(Exception):
    """Root of every monoguide failure. ``code`` and ``plc_code`` are stable across releases."""

    code = "MONOGUIDE_ERROR"
    plc_code = 1

    def __init__(self, message: str) -> None:
        super().__init__(message)
        self.message = message

    def as_dict(self) -> dict[str, str]:
        return {"code": self.code, "message": self.message}


# --- measurement record (1xx) -------------------------------------------------------------------


class RecordError(MonoguideError):
    """A measurement record is malformed; the message names the field and the value."""

    code = "RECORD_INVALID"
    plc_code = 100


class UnsupportedFormat(RecordError):
    code = "RECORD_FORMAT"
    plc_code = 101


class NonFiniteValue(RecordError):
    code = "RECORD_NONFINITE"
    plc_code = 102


class UnknownReference(RecordError):
    """An observation names a view or point that does not exist, or repeats a point in a view."""

    code = "RECORD_REFERENCE"
    plc_code = 103


class NotARotation(RecordError):
    code = "RECORD_NOT_A_ROTATION"
    plc_code = 104


class MissingKey(RecordError):
    """A required key of the record (or of one of its objects) is absent: nothing defaults silently."""

    code = "RECORD_MISSING_KEY"
    plc_code = 107


class UnknownKey(RecordError):
    """A key the format does not define (often a typo, ``sigma_pix``): refused, never dropped."""

    code = "RECORD_UNKNOWN_KEY"
    plc_code = 108

    @classmethod
    def naming(cls, key: str, known: Iterable[str], where: str) -> UnknownKey:
        """The error for ``key`` in the object at ``where``, suggesting the closest of ``known``."""
        close = difflib.get_close_matches(key, sorted(known), n=1, cutoff=0.6)
        hint = f"; did you mean {close[0]}?" if close else f"; known keys: {', '.join(sorted(known))}"
        place = f"{where}: " if where else ""
        return cls(f"{place}unknown key {key!r}{hint}")


# --- pose solve (2xx) ---------------------------------------------------------------------------


class SolveFailed(MonoguideError):
    code = "SOLVE_FAILED"
    plc_code = 200


class TooFewObservations(SolveFailed):
    code = "TOO_FEW_OBSERVATIONS"
    plc_code = 201


class NoConvergence(SolveFailed):
    code = "NO_CONVERGENCE"
    plc_code = 202


class DegenerateGeometry(SolveFailed):
    """The views do not constrain all six degrees of freedom (e.g. all rays nearly parallel)."""

    code = "DEGENERATE_GEOMETRY"
    plc_code = 203


class PointBehindCamera(SolveFailed):
    code = "POINT_BEHIND_CAMERA"
    plc_code = 204


class ResidualTooLarge(SolveFailed):
    code = "RESIDUAL_TOO_LARGE"
    plc_code = 205


class UncertaintyTooLarge(SolveFailed):
    code = "UNCERTAINTY_TOO_LARGE"
    plc_code = 206


class InconsistentMeasurement(SolveFailed):
    """The residual of the solve is too large for the stated noise (chi-square test): some centre,
    calibration or record is wrong. The message names the observation that explains most of it."""

    code = "INCONSISTENT_MEASUREMENT"
    plc_code = 207


class CalibrationSuspect(SolveFailed):
    """The cell's calibration no longer fits what the camera sees: a view's camera stood further from its
    calibrated pose than the tolerance (fixed marks, the check job) or the trend monitor passed its alarm level.
    The message names the view and the deviation in mm and deg; nothing is written to the robot."""

    code = "CALIBRATION_SUSPECT"
    plc_code = 208


# --- hole detection (3xx) -----------------------------------------------------------------------


class FeatureNotFound(MonoguideError):
    """A featured hole could not be measured in an image."""

    code = "FEATURE_NOT_FOUND"
    plc_code = 300


class HoleNotFound(FeatureNotFound):
    code = "HOLE_NOT_FOUND"
    plc_code = 301


class HoleCutByBorder(FeatureNotFound):
    code = "HOLE_CUT_BY_BORDER"
    plc_code = 302


class HoleAmbiguous(FeatureNotFound):
    """Two or more plausible candidates where one hole is expected: refused rather than guessed."""

    code = "HOLE_AMBIGUOUS"
    plc_code = 303


class LowContrast(FeatureNotFound):
    """The hole's rim is too blurred or too faint to place it to the required accuracy."""

    code = "LOW_CONTRAST"
    plc_code = 304


class ImageSaturated(FeatureNotFound):
    code = "IMAGE_SATURATED"
    plc_code = 305


class BadImage(FeatureNotFound):
    """The image has the wrong shape or dtype, or is empty."""

    code = "BAD_IMAGE"
    plc_code = 306


class MarkNotFound(FeatureNotFound):
    """A fixed reference mark a measuring pose should see was not found where the calibration puts it: hidden (a
    part out of place, a cable, dirt), damaged, or the camera no longer where it was calibrated."""

    code = "MARK_NOT_FOUND"
    plc_code = 307


# --- offset checks (5xx) ------------------------------------------------------------------------


class OffsetOutOfEnvelope(MonoguideError):
    """The solved part displacement lies outside the configured envelope: nothing is written."""

    code = "OFFSET_OUT_OF_ENVELOPE"
    plc_code = 501


def all_error_classes() -> list[type[MonoguideError]]:
    """Every subclass of :class:`MonoguideError` imported so far, the root first."""
    found: list[type[MonoguideError]] = [MonoguideError]
    stack: list[type[MonoguideError]] = [MonoguideError]
    while stack:
        for sub in stack.pop().__subclasses__():
            found.append(sub)
            stack.append(sub)
    return found
