"""Failures of a calibration step (plc_code 700-729). Each message names the points, poses or images at fault."""

from __future__ import annotations

from monoguide.solver.errors import MonoguideError


class CalibrationError(MonoguideError):
    """A calibration step could not produce a trustworthy result."""

    code = "CALIBRATION_FAILED"
    plc_code = 700


class CalibrationDegenerate(CalibrationError):
    """The measured geometry does not constrain the result (collinear points, poses without rotation)."""

    code = "CALIBRATION_DEGENERATE"
    plc_code = 701


class CalibrationTooFewViews(CalibrationError):
    """Fewer points, poses, visits or usable images than the step needs."""

    code = "CALIBRATION_TOO_FEW_VIEWS"
    plc_code = 702


class CalibrationResidualTooLarge(CalibrationError):
    """The fit's residual exceeds the tolerance: a point was mis-measured, an SMR moved, a nest is wrong."""

    code = "CALIBRATION_RESIDUAL_TOO_LARGE"
    plc_code = 703


class CalibrationImageRejected(CalibrationError):
    """An image is unusable (plate or target not found, blurred); the message says why."""

    code = "CALIBRATION_IMAGE_REJECTED"
    plc_code = 704


class CalibrationSpreadTooLarge(CalibrationError):
    """The visits of a measuring pose disagree by more than the robot's repeatability explains."""

    code = "CALIBRATION_SPREAD_TOO_LARGE"
    plc_code = 705
