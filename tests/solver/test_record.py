"""The measurement record: every bad-record code, and the example record against its truth."""

import copy
import json
from pathlib import Path

import numpy as np
import pytest

from monoguide.solver import frames
from monoguide.solver.errors import (
    NonFiniteValue,
    NotARotation,
    PointBehindCamera,
    RecordError,
    TooFewObservations,
    UnknownReference,
    UnsupportedFormat,
)
from monoguide.solver.pose import solve_pose
from monoguide.solver.record import parse_record, result_to_dict

EXAMPLE = json.loads((Path(__file__).parents[2] / "examples" / "example-record.json").read_text())


@pytest.mark.parametrize("method", ["ml", "paper"])
def test_example_record_solves_to_its_truth_within_its_noise(method):
    record = parse_record(EXAMPLE)
    result = solve_pose(record.problem, method)
    truth = record.truth_T_s1_w
    e = np.concatenate(
        [frames.matrix_to_rotvec(truth[:3, :3] @ result.T_s1_w[:3, :3].T), truth[:3, 3] - result.T_s1_w[:3, 3]]
    )
    # within the 99.9 % ellipsoid of its own covariance (chi-square, 6 degrees of freedom: 22.5)
    assert e @ np.linalg.solve(result.covariance, e) < 22.5
    assert frames.pose_difference(result.T_s1_w, truth)[1] < 0.5


def test_result_has_exactly_the_spec_fields_and_the_offset_of_eq5():
    record = parse_record(EXAMPLE)
    result = solve_pose(record.problem)
    out = result_to_dict(record.id, result, record.problem.T_s1_w0, 1.0)
    assert set(out) == {"id", "status", "T_s1_w", "offset", "rms_px", "covariance", "sigma_rot_deg",
                        "sigma_trans_mm", "method", "iterations", "time_ms"}
    T_s1_w0 = np.array(EXAMPLE["T_s1_w0"])
    # the spec's definition of the offset, applied to the reported pose (the record's matrices are printed
    # to 6 decimals, so its T_s1_w0 is orthonormal to 1e-6 only: 650 mm x 1e-6)
    np.testing.assert_allclose(np.array(out["offset"]), np.array(out["T_s1_w"]) @ np.linalg.inv(T_s1_w0), atol=2e-3)
    truth_offset = record.truth_T_s1_w @ np.linalg.inv(T_s1_w0)
    d_rot, d_mm = frames.pose_difference(np.array(out["offset"]), truth_offset)
    assert d_rot < 0.05 and d_mm < 0.5
    assert out["id"] == "example-1" and out["status"] == "ok"


def _broken(path, value):
    data = copy.deepcopy(EXAMPLE)
    target = data
    for key in path[:-1]:
        target = target[key]
    if value is _DELETE:
        del target[path[-1]]
    else:
        target[path[-1]] = value
    return data


_DELETE = object()


@pytest.mark.parametrize(
    ("path", "value", "error", "fragment"),
    [
        (("format",), "monoguide.measurement/2", UnsupportedFormat, "format"),
        (("format",), _DELETE, UnsupportedFormat, "format"),
        (("points_w", 1, 0), float("nan"), NonFiniteValue, r"points_w\[1\]\[0\]"),
        (("observations", 2, "pixel"), [float("inf"), 3.0], NonFiniteValue, r"observations\[2\]\.pixel"),
        (("observations", 1, "view"), 7, UnknownReference, r"observations\[1\]\.view: 7"),
        (("observations", 1, "point"), -1, UnknownReference, r"observations\[1\]\.point: -1"),
        (("observations", 3, "point"), "a", RecordError, "integer"),
        (("views", 1, "T_s1_si", 0, 0), 1.2, NotARotation, r"views\[1\]\.T_s1_si"),
        (("T_s1_w0", 0, 0), -0.5, NotARotation, "T_s1_w0"),
        (("camera", "fx"), "big", RecordError, r"camera\.fx"),
        (("camera",), _DELETE, RecordError, "camera: missing"),
        (("sigma_px",), -0.1, RecordError, "sigma_px"),
        (("observations",), [], TooFewObservations, "0 observation"),
        (("observations", 0, "pixel"), [5000.0, 100.0], RecordError, "outside"),
        (("views", 0, "T_s1_si"), [[1, 0, 0, 10], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], RecordError, "identity"),
    ],
)
def test_bad_record_gets_its_code(path, value, error, fragment):
    with pytest.raises(error, match=fragment) as info:
        parse_record(_broken(path, value))
    assert info.value.code  # every error carries a stable code for the result line


def test_same_point_twice_in_one_view():
    data = copy.deepcopy(EXAMPLE)
    data["observations"].append(dict(data["observations"][0]))
    with pytest.raises(UnknownReference, match="twice"):
        parse_record(data)


def test_point_behind_the_camera_at_the_reference_pose():
    data = copy.deepcopy(EXAMPLE)
    data["T_s1_w0"][2][3] = -650.0  # the reference part behind the first camera
    with pytest.raises(PointBehindCamera, match="behind camera"):
        parse_record(data)


def test_a_record_that_is_not_an_object():
    with pytest.raises(RecordError, match="JSON object"):
        parse_record([1, 2, 3])
