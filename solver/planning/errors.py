"""Why a measuring layout cannot be planned (``plc_code`` 510-529).

Each refusal names the constraint that binds: the one whose relaxation would let the request be planned.
"""

from __future__ import annotations

from monoguide.solver.errors import MonoguideError


class LayoutInfeasible(MonoguideError):
    """No measuring layout satisfies the request; the message names the binding constraint."""

    code = "LAYOUT_INFEASIBLE"
    plc_code = 510


class LayoutRequestInvalid(LayoutInfeasible):
    """A value of the request is not usable (not finite, a range with min > max, ...); named with its value."""

    code = "LAYOUT_REQUEST_INVALID"
    plc_code = 511


class LayoutTooFewPoints(LayoutInfeasible):
    """Fewer than three featured points, or all of them on one line: a direction of the pose is unobservable."""

    code = "LAYOUT_TOO_FEW_POINTS"
    plc_code = 512


class LayoutOutOfView(LayoutInfeasible):
    """No allowed pose keeps a hole inside the image with the required margin over the whole envelope."""

    code = "LAYOUT_OUT_OF_VIEW"
    plc_code = 513


class LayoutDepthOfField(LayoutInfeasible):
    """No allowed pose keeps a hole inside the depth of field over the whole envelope."""

    code = "LAYOUT_DEPTH_OF_FIELD"
    plc_code = 514


class LayoutViewAngle(LayoutInfeasible):
    """The allowed angles between line of sight and surface normal leave no layout: within
    ``max_view_angle_deg`` the lines of sight cannot observe every direction of the pose (all parallel: the
    part's distance is unobservable), or no pose keeps them within ``max_view_angle_envelope_deg`` over the
    whole envelope."""

    code = "LAYOUT_VIEW_ANGLE"
    plc_code = 515


class LayoutOutOfReach(LayoutInfeasible):
    """No allowed pose puts the robot's flange inside its reach region."""

    code = "LAYOUT_OUT_OF_REACH"
    plc_code = 516


class LayoutStandoff(LayoutInfeasible):
    """The standoff range binds: other standoffs would hold every other constraint over the envelope."""

    code = "LAYOUT_STANDOFF"
    plc_code = 518


class LayoutConstraintsConflict(LayoutInfeasible):
    """Several constraints bind together: relaxing any single one of them is not enough."""

    code = "LAYOUT_CONSTRAINTS_CONFLICT"
    plc_code = 517
