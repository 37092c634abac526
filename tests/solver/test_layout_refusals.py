"""An infeasible layout request is refused with a typed error naming the constraint that binds."""

from __future__ import annotations

import math

import numpy as np
import pytest

from monoguide.solver.camera import PAPER_CAMERA
from monoguide.solver.errors import MonoguideError, all_error_classes
from monoguide.solver.planning import (
    DeviationEnvelope,
    LayoutConstraints,
    LayoutConstraintsConflict,
    LayoutDepthOfField,
    LayoutInfeasible,
    LayoutOutOfReach,
    LayoutOutOfView,
    LayoutRequest,
    LayoutRequestInvalid,
    LayoutStandoff,
    LayoutTooFewPoints,
    LayoutViewAngle,
    ReachRegion,
    plan_layout,
)
from monoguide.solver.synthetic import PAPER_ROOF_POINTS_W

SMALL = DeviationEnvelope((20.0, 20.0, 20.0), (2.0, 2.0, 2.0))
PAPERS = DeviationEnvelope()  # +-50 mm, +-5 deg on every axis


def request(constraints: LayoutConstraints, envelope: DeviationEnvelope = PAPERS, **kw):
    return LayoutRequest(PAPER_CAMERA, kw.pop("points_w", PAPER_ROOF_POINTS_W), envelope, constraints, **kw)


@pytest.mark.parametrize(
    ("the_request", "error", "says"),
    [
        # +-50 mm / +-5 deg cannot stay 100 px inside the image from 300-320 mm
        (request(LayoutConstraints((300.0, 320.0), 30.0, 100.0, (100.0, 2000.0))), LayoutOutOfView,
         r"margin_px: no measuring pose \(standoff 300-320 mm.*keeps hole P\d 100 px inside the image.*±50/50/50"),
        # the depth over the envelope spans some 400 mm; 640-660 mm holds 20
        (request(LayoutConstraints((400.0, 1000.0), 30.0, 100.0, (640.0, 660.0))), LayoutDepthOfField,
         r"depth_of_field_mm: no measuring pose .* inside the depth of field 640-660 mm"),
        # straight down on every hole with the hole centred: parallel lines of sight, the distance unseen
        (request(LayoutConstraints((400.0, 1000.0), 0.0, 100.0, (300.0, 1200.0))), LayoutViewAngle,
         r"max_view_angle_deg = 0° .* unobservable"),
        # a part turning +-5 deg under a camera 400-1000 mm away: no line of sight stays within 15 deg
        (request(LayoutConstraints((400.0, 1000.0), 30.0, 100.0, (300.0, 1200.0), max_view_angle_envelope_deg=15.0)),
         LayoutViewAngle, r"max_view_angle_envelope_deg: .* within 15° of its surface normal"),
        # the robot stands 10 m away with a 2 m reach
        (request(LayoutConstraints((400.0, 1000.0), 30.0, 100.0, (300.0, 1200.0),
                                   ReachRegion((10000.0, 0.0, 0.0), 2000.0))),
         LayoutOutOfReach, r"reach: no measuring pose .* within 2000 mm of the reach centre"),
        # 800 px of margin needs a long standoff, a far limit of 450 mm a short one
        (request(LayoutConstraints((150.0, 1000.0), 30.0, 800.0, (100.0, 450.0)), SMALL), LayoutConstraintsConflict,
         r"margin_px and depth_of_field_mm cannot hold together .* relaxing either would do"),
        # 300-320 mm is too close for a depth of field of 450-900 mm; 650-700 mm would hold everything
        (request(LayoutConstraints((300.0, 320.0), 30.0, 100.0, (450.0, 900.0))), LayoutStandoff,
         r"standoff_mm = \[300, 320\]: .*every hole can be held at standoffs of \d+-\d+ mm: widen the range"),
        # +-500 mm: no standoff at all keeps 100 px of margin inside a 450-900 mm depth of field
        (request(LayoutConstraints((400.0, 1000.0), 30.0, 100.0, (450.0, 900.0)),
                 DeviationEnvelope((500.0, 500.0, 500.0), (5.0, 5.0, 5.0))), LayoutConstraintsConflict,
         r"margin_px, depth_of_field_mm together over the envelope ±500/500/500 mm.* nor at any from 50 to 5000 mm"),
        (request(LayoutConstraints(), points_w=PAPER_ROOF_POINTS_W[:2]), LayoutTooFewPoints,
         r"2 featured point\(s\)"),
        (request(LayoutConstraints(), points_w=np.array([[0.0, 0, 0], [500.0, 0, 0], [1000.0, 0, 0]])),
         LayoutTooFewPoints, r"lie on one line"),
    ],
    ids=["out of view", "depth of field", "view angle", "view angle over the envelope", "reach", "conflict",
         "standoff", "envelope no standoff holds", "two holes", "collinear holes"],
)
def test_a_refusal_names_the_binding_constraint(the_request, error, says):
    with pytest.raises(error, match=says) as caught:
        plan_layout(the_request)
    assert type(caught.value) is error


@pytest.mark.parametrize(
    ("changes", "says"),
    [
        ({"sigma_px": math.nan}, r"sigma_px = nan"),
        ({"sigma_px": 0.0}, r"sigma_px = 0.0"),
        ({"repeatability_mm": -0.1}, r"repeatability_mm = -0.1"),
        ({"constraints": LayoutConstraints(standoff_mm=(900.0, 400.0))}, r"standoff_mm = \[900.0, 400.0\]"),
        ({"constraints": LayoutConstraints(depth_of_field_mm=(0.0, 400.0))}, r"depth_of_field_mm = \[0.0, 400.0\]"),
        ({"constraints": LayoutConstraints(margin_px=-5.0)}, r"margin_px = -5.0"),
        ({"constraints": LayoutConstraints(max_view_angle_deg=95.0)}, r"max_view_angle_deg = 95.0"),
        ({"envelope": DeviationEnvelope(rotation_deg=(5.0, 50.0, 5.0))}, r"rotation_deg = \[5.0, 50.0, 5.0\]"),
        ({"normals_w": np.zeros((4, 3))}, r"normals_w"),
        ({"grasp_point_w": np.array([0.0, math.inf, 0.0])}, r"grasp_point_w"),
    ],
)
def test_an_unusable_request_is_refused_naming_the_value(changes, says):
    with pytest.raises(LayoutRequestInvalid, match=says):
        plan_layout(LayoutRequest(PAPER_CAMERA, PAPER_ROOF_POINTS_W, **changes))


def test_layout_error_codes_are_unique_and_in_the_planning_range():
    layout_errors = [c for c in all_error_classes() if issubclass(c, LayoutInfeasible)]
    assert len(layout_errors) == 9
    assert all(510 <= c.plc_code <= 529 for c in layout_errors)
    assert len({c.plc_code for c in layout_errors}) == len(layout_errors)
    others = [c for c in all_error_classes() if not issubclass(c, LayoutInfeasible)]
    assert not {c.plc_code for c in layout_errors} & {c.plc_code for c in others}
    assert not {c.code for c in layout_errors} & {c.code for c in others}
    assert all(issubclass(c, MonoguideError) for c in layout_errors)
