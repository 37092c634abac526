"""Measuring-pose planning (Section 4): where the cameras stand so that the part pose is measured best.

- :mod:`.fig5` the paper's own study: cameras looking straight down, holes moved outwards in the image
- :mod:`.prediction` the predicted covariance of a layout and its sigmas at the grasp point (Eq. 29)
- :mod:`.envelope` the part's deviation envelope and what a camera sees of a hole over all of it
- :mod:`.request` a layout request and the assessment of any layout against it
- :mod:`.layout` the planner: tilted, converging views that hold the whole envelope
- :mod:`.marks` whether each view sees its fixed marks: in its image, apart, never behind a part in its envelope
- :mod:`.errors` why a layout cannot be planned (plc codes 510-529)

Frames: ``T_w0_si`` is measuring pose i in the frame of the reference part; the cell config stores
``T_cf_si = T_cf_w0 @ T_w0_si``.
"""

from monoguide.solver.planning.envelope import DeviationEnvelope, envelope_deviations, hole_in_view
from monoguide.solver.planning.errors import (
    LayoutConstraintsConflict,
    LayoutDepthOfField,
    LayoutInfeasible,
    LayoutOutOfReach,
    LayoutOutOfView,
    LayoutRequestInvalid,
    LayoutStandoff,
    LayoutTooFewPoints,
    LayoutViewAngle,
)
from monoguide.solver.planning.fig5 import (
    R_W_C_LOOKING_DOWN,
    UncertaintyMap,
    look_at_poses,
    quarter_targets,
    uncertainty_map,
)
from monoguide.solver.planning.layout import CameraPlacement, camera_pose_for, plan_layout
from monoguide.solver.planning.marks import (
    Mark,
    MarkedView,
    MarksVisibility,
    MarkVisibility,
    PartSheet,
    check_marks,
)
from monoguide.solver.planning.prediction import PoseSigmas, layout_covariance, observed_covariance, pose_sigmas
from monoguide.solver.planning.request import (
    LayoutAssessment,
    LayoutConstraints,
    LayoutRequest,
    ReachRegion,
    assess_layout,
    validate_request,
)

__all__ = [
    "R_W_C_LOOKING_DOWN",
    "CameraPlacement",
    "DeviationEnvelope",
    "LayoutAssessment",
    "LayoutConstraints",
    "LayoutConstraintsConflict",
    "LayoutDepthOfField",
    "LayoutInfeasible",
    "LayoutOutOfReach",
    "LayoutOutOfView",
    "LayoutRequest",
    "LayoutRequestInvalid",
    "LayoutStandoff",
    "LayoutTooFewPoints",
    "LayoutViewAngle",
    "Mark",
    "MarkVisibility",
    "MarkedView",
    "MarksVisibility",
    "PartSheet",
    "PoseSigmas",
    "ReachRegion",
    "UncertaintyMap",
    "assess_layout",
    "camera_pose_for",
    "check_marks",
    "envelope_deviations",
    "hole_in_view",
    "layout_covariance",
    "look_at_poses",
    "observed_covariance",
    "plan_layout",
    "pose_sigmas",
    "quarter_targets",
    "uncertainty_map",
    "validate_request",
]
