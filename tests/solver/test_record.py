"""The measurement record: every bad-record code, strict keys, rounded matrices, and the example record's
results against its truth (pose, displacement, grasp-point shift, base offset)."""

import copy
import json
from pathlib import Path

import numpy as np
import pytest

from monoguide.solver import frames
from monoguide.solver.envelope import DeviationEnvelope
from monoguide.solver.errors import (
    MissingKey,
    NonFiniteValue,
    NotARotation,
    OffsetOutOfEnvelope,
    PointBehindCamera,
    RecordError,
    TooFewObservations,
    UnknownKey,
    UnknownReference,
    UnsupportedFormat,
)
from monoguide.solver.pose import solve_pose
from monoguide.solver.record import envelope_to_record, parse_record, result_to_dict, solve_record

EXAMPLE = json.loads((Path(__file__).parents[2] / "examples" / "example-record.json").read_text())
RESULT_FIELDS = {
    "id", "status", "T_s1_w", "displacement_s1", "grasp_point_w", "grasp_shift_mm", "grasp_shift_s1_mm",
    "rotation_deg", "base_offset", "base_offset_xyzabc", "rms_px", "covariance", "sigma_rot_deg",
    "sigma_trans_mm", "consistency", "method", "iterations", "time_ms",
}


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


def test_example_result_against_the_truth_of_the_cell():
    """Every reported quantity against the record's truth (where the part really was), in its frame: the
    grasp point moves as the true part moves it, and the base offset carries the reference part onto the
    true one in the robot base frame."""
    record = parse_record(EXAMPLE)
    out = result_to_dict(record, solve_pose(record.problem), 1.0)
    assert set(out) == RESULT_FIELDS
    assert out["id"] == "example-1" and out["status"] == "ok"
    T_s1_w0, T_true = np.array(EXAMPLE["T_s1_w0"]), np.array(EXAMPLE["truth"]["T_s1_w"])
    # the grasp point (the record's, here the holes' centroid) in SF1 before and after
    g_w = np.append(np.array(EXAMPLE["grasp_point_w"]), 1.0)
    true_shift_s1 = (T_true @ g_w - T_s1_w0 @ g_w)[:3]
    np.testing.assert_allclose(out["grasp_shift_s1_mm"], true_shift_s1, atol=0.3)
    assert out["grasp_shift_mm"] == pytest.approx(np.linalg.norm(true_shift_s1), abs=0.3)
    true_angle = frames.rotation_angle_deg(T_true[:3, :3] @ T_s1_w0[:3, :3].T)
    assert out["rotation_deg"] == pytest.approx(true_angle, abs=0.02)
    # the base offset: the true part in the robot base frame, moved back onto the reference
    T_b_s1 = np.array(EXAMPLE["T_b_s1"])
    true_base_offset = np.array(EXAMPLE["truth"]["base_offset"])
    np.testing.assert_allclose(true_base_offset, (T_b_s1 @ T_true) @ np.linalg.inv(T_b_s1 @ T_s1_w0), atol=2e-3)
    D_b = np.array(out["base_offset"])
    g_b = T_b_s1 @ T_s1_w0 @ g_w  # the grasp point on the reference part, in the base frame
    assert np.linalg.norm(D_b @ g_b - true_base_offset @ g_b) < 0.3  # where the robot grips, mm
    assert frames.pose_difference(D_b, true_base_offset)[0] < 0.02
    x, y, z, a, b, c = out["base_offset_xyzabc"]
    np.testing.assert_allclose(frames.kuka_frame_to_T(x, y, z, a, b, c), D_b, atol=1e-6)
    assert out["consistency"]["dof"] == 2 and out["consistency"]["chi2"] < out["consistency"]["threshold"]


def test_a_record_without_T_b_s1_has_no_base_offset_and_the_centroid_as_grasp_point():
    data = copy.deepcopy(EXAMPLE)
    for key in ("T_b_s1", "grasp_point_w", "envelope"):
        del data[key]
    record = parse_record(data)
    centroid = np.mean(EXAMPLE["points_w"], axis=0)
    assert record.T_b_s1 is None
    np.testing.assert_allclose(record.grasp_point_w, centroid)
    # the default envelope: +-50 mm / +-5 deg per axis about the holes' centroid, totals the norms
    assert record.envelope.translation_mm == (50.0,) * 3 and record.envelope.rotation_deg == (5.0,) * 3
    np.testing.assert_allclose(record.envelope.about_w, centroid)
    assert record.envelope.limit_mm == pytest.approx(50.0 * 3**0.5)
    out = result_to_dict(record, solve_pose(record.problem), 1.0)
    assert out["base_offset"] is None and out["base_offset_xyzabc"] is None
    assert "offset" not in out


def _reported(data):
    record = parse_record(data)
    return record, result_to_dict(record, solve_pose(record.problem), 1.0)


@pytest.mark.parametrize("how", ["absent", "null"])
def test_sigma_px_is_optional_and_defaults_to_a_tenth_of_a_pixel(how):
    """The spec's default (0.1 px) when a record has no sigma_px (or null): the covariance scales with the
    square of the centre noise and the whitened residual with its inverse square, so against the same
    pixels stated at 0.2 px the default's covariance is a quarter and its chi-square four times as large."""
    data = copy.deepcopy(EXAMPLE)
    if how == "absent":
        del data["sigma_px"]
    else:
        data["sigma_px"] = None
    record, default = _reported(data)
    assert record.problem.sigma_px == 0.1
    assert default["status"] == "ok" and default["consistency"]["sigma_px"] == 0.1
    data["sigma_px"] = 0.2
    _, doubled = _reported(data)
    assert doubled["consistency"]["sigma_px"] == 0.2
    np.testing.assert_allclose(doubled["T_s1_w"], default["T_s1_w"], atol=1e-9)  # scaling does not move the fit
    np.testing.assert_allclose(np.array(doubled["covariance"]), 4.0 * np.array(default["covariance"]),
                               rtol=1e-4, atol=1e-15)
    # reported to 6 decimals: within the rounding of both
    assert doubled["sigma_trans_mm"] == pytest.approx(2.0 * default["sigma_trans_mm"], abs=2e-6)
    assert doubled["sigma_rot_deg"] == pytest.approx(2.0 * default["sigma_rot_deg"], abs=2e-6)
    assert default["consistency"]["chi2"] == pytest.approx(4.0 * doubled["consistency"]["chi2"], rel=1e-4)
    # and the default is the example's own 0.1 px, written out
    _, stated = _reported(EXAMPLE)
    assert EXAMPLE["sigma_px"] == 0.1
    np.testing.assert_allclose(np.array(default["covariance"]), np.array(stated["covariance"]), rtol=1e-9)


def test_an_old_records_envelope_is_read_as_it_was_judged_at_the_grasp_point():
    """The old form: totals ``mm`` / ``deg``, per-axis limits ``axis_mm`` / ``axis_deg`` (default: the totals),
    the shift judged at the grasp point."""
    data = copy.deepcopy(EXAMPLE)
    data["grasp_point_w"] = [100.0, 200.0, 0.0]
    data["envelope"] = {"mm": 40.0, "deg": 3.0, "axis_mm": [40.0, 40.0, 5.0]}
    assert parse_record(data).envelope == DeviationEnvelope((40.0, 40.0, 5.0), (3.0, 3.0, 3.0), (100.0, 200.0, 0.0),
                                                            40.0, 3.0)


def test_the_records_envelope_round_trips_with_its_point_and_totals():
    data = copy.deepcopy(EXAMPLE)
    for envelope in (DeviationEnvelope((40.0, 30.0, 20.0), (3.0, 2.0, 4.0), (750.0, 500.0, 10.0), 45.0, 4.5),
                     DeviationEnvelope((50.0, 50.0, 5.0), (0.5, 0.5, 2.0), (1.0, 2.0, 3.0))):
        data["envelope"] = json.loads(json.dumps(envelope_to_record(envelope)))
        assert parse_record(data).envelope == envelope
    data["envelope"] = {"translation_mm": [10.0, 10.0, 10.0], "rotation_deg": [1.0, 1.0, 1.0]}
    parsed = parse_record(data).envelope  # no about_w: the holes' centroid; no totals: the norms
    np.testing.assert_allclose(parsed.about_w, np.mean(EXAMPLE["points_w"], axis=0))
    assert (parsed.limit_mm, parsed.limit_deg) == pytest.approx((10.0 * 3**0.5, 3**0.5))


def test_solve_judges_the_record_about_its_envelopes_point():
    """The example part's true shift, computed here from its truth (``T_w0_w a - a``), at the centroid and at a
    point 3 m off it: with a per-axis limit between the two, solve passes the part about the centroid and
    refuses it about the far point."""
    data = copy.deepcopy(EXAMPLE)
    T_w0_w = np.linalg.inv(np.array(EXAMPLE["T_s1_w0"])) @ np.array(EXAMPLE["truth"]["T_s1_w"])
    centroid = np.mean(EXAMPLE["points_w"], axis=0)
    far = centroid + np.array([0.0, 3000.0, 0.0])
    shift_centroid, shift_far = (np.abs(T_w0_w[:3, :3] @ a + T_w0_w[:3, 3] - a).max() for a in (centroid, far))
    assert shift_far > shift_centroid + 20.0  # the seeded part turns enough for the two points to differ
    limit = (shift_centroid + shift_far) / 2.0
    data["envelope"] = {"translation_mm": [limit] * 3, "rotation_deg": [5.0, 5.0, 5.0]}
    record = parse_record(data)
    moved = record.displacement(record.truth_T_s1_w).about_shift_w0
    np.testing.assert_allclose(moved, T_w0_w[:3, :3] @ centroid + T_w0_w[:3, 3] - centroid, atol=1e-3)
    assert solve_record(data)[0]["status"] == "ok"
    data["envelope"]["about_w"] = far.tolist()
    out = solve_record(data)[0]
    assert out["status"] == "error" and out["error"]["code"] == OffsetOutOfEnvelope.code
    assert "at (" + ", ".join(f"{v:.2f}" for v in far) + ") mm" in out["error"]["message"]


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
        (("T_b_s1", 1, 1), 0.5, NotARotation, "T_b_s1"),
        (("camera", "fx"), "big", RecordError, r"camera\.fx"),
        (("camera",), _DELETE, MissingKey, "camera: missing"),
        (("camera", "k1"), _DELETE, MissingKey, r"camera\.k1: missing"),
        (("camera", "p2"), _DELETE, MissingKey, r"camera\.p2: missing"),
        (("observations", 0, "pixel"), _DELETE, MissingKey, r"observations\[0\]\.pixel: missing"),
        (("views", 2, "T_s1_si"), _DELETE, MissingKey, r"views\[2\]\.T_s1_si: missing"),
        (("sigma_px",), -0.1, RecordError, "sigma_px"),
        (("job",), 0, RecordError, r"job: expected the PLC's job number, an integer 1 to 65535, got 0"),
        (("job",), True, RecordError, r"job: .* got True"),
        (("part",), " ", RecordError, r"part: expected the part type's name"),
        (("grasp_point_w",), [1.0, 2.0], RecordError, "grasp_point_w"),
        (("envelope", "mm"), 0.0, RecordError, r"envelope\.mm"),
        (("envelope", "deg"), _DELETE, MissingKey, r"envelope\.deg: missing"),
        (("envelope", "translation_mm"), [1.0, 1.0, 1.0], RecordError, r"translation_mm beside the old form"),
        (("envelope",), {"translation_mm": [1.0, 1.0, 1.0]}, MissingKey, r"envelope\.rotation_deg: missing"),
        (("envelope",), {"translation_mm": [1.0, 0.0, 1.0], "rotation_deg": [1.0, 1.0, 1.0]}, RecordError,
         r"envelope\.translation_mm\[1\]: must be positive"),
        (("envelope",), {"translation_mm": [1.0, 1.0, 1.0], "rotation_deg": [1.0, 1.0, 1.0], "total_mm": -1.0},
         RecordError, r"envelope\.total_mm: must be positive"),
        (("envelope",), {"translation_mm": [1.0, 1.0, 1.0], "rotation_deg": [1.0, 1.0, 1.0], "about_w": [1.0]},
         RecordError, r"envelope\.about_w"),
        (("truth", "T_s1_w"), _DELETE, MissingKey, r"truth\.T_s1_w: missing"),
        (("observations",), [], TooFewObservations, "0 observation"),
        (("observations", 0, "pixel"), [5000.0, 100.0], RecordError, "outside"),
        (("views", 0, "T_s1_si"), [[1, 0, 0, 10], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], RecordError, "identity"),
    ],
)
def test_bad_record_gets_its_code(path, value, error, fragment):
    with pytest.raises(error, match=fragment) as info:
        parse_record(_broken(path, value))
    assert info.value.code  # every error carries a stable code for the result line


@pytest.mark.parametrize(
    ("path", "key", "fragment"),
    [
        ((), "sigma_pix", r"unknown key 'sigma_pix'; did you mean sigma_px\?"),
        ((), "T_b_s", r"did you mean T_b_s1\?"),
        ((), "offset", r"unknown key 'offset'"),
        (("camera",), "k3", r"camera: unknown key 'k3'; known keys: cx, cy, fx, fy, height, k1, k2, p1, p2"),
        (("camera",), "fxx", r"camera: unknown key 'fxx'; did you mean fx\?"),
        (("views", 1), "T_s1_s", r"views\[1\]: unknown key 'T_s1_s'; did you mean T_s1_si\?"),
        (("observations", 2), "pixels", r"observations\[2\]: unknown key 'pixels'; did you mean pixel\?"),
        (("envelope",), "axis_m", r"envelope: unknown key 'axis_m'; did you mean axis_mm\?"),
        (("envelope",), "about", r"envelope: unknown key 'about'"),
        (("truth",), "T_s1_ww", r"truth: unknown key 'T_s1_ww'; did you mean T_s1_w\?"),
    ],
)
def test_unknown_keys_are_refused_with_the_closest_known_one(path, key, fragment):
    data = copy.deepcopy(EXAMPLE)
    target = data
    for step in path:
        target = target[step]
    target[key] = 1.0
    with pytest.raises(UnknownKey, match=fragment) as info:
        parse_record(data)
    assert info.value.code == "RECORD_UNKNOWN_KEY"


def test_unknown_key_in_view_sigma():
    data = copy.deepcopy(EXAMPLE)
    data["view_sigma"] = {"mm": 0.05, "degree": 0.01}
    with pytest.raises(UnknownKey, match=r"view_sigma: unknown key 'degree'; did you mean deg\?"):
        parse_record(data)


def test_missing_k1_is_not_a_silent_zero():
    """The old reader solved a record without k1 with k1 = 0 (millimetres off); now it names the key."""
    data = copy.deepcopy(EXAMPLE)
    del data["camera"]["k1"]
    with pytest.raises(MissingKey, match=r"camera\.k1: missing"):
        parse_record(data)


def _rounded(matrix, decimals):
    return [[round(v, decimals) for v in row] for row in matrix]


def test_matrices_rounded_to_5_decimals_are_accepted_and_orthonormalised():
    data = copy.deepcopy(EXAMPLE)
    R = frames.rotvec_to_matrix(np.radians([3.0, -2.0, 177.0]))
    T = frames.make_T(R, [162.252524, -123.153672, 650.0])
    data["T_s1_w0"] = _rounded(T.tolist(), 5)
    R5 = np.array(data["T_s1_w0"])[:3, :3]
    assert 1e-6 < np.max(np.abs(R5.T @ R5 - np.eye(3))) < 1e-4  # what the old reader refused
    T_s1_w0 = parse_record(data).problem.T_s1_w0
    np.testing.assert_allclose(T_s1_w0[:3, :3].T @ T_s1_w0[:3, :3], np.eye(3), atol=1e-14)
    assert frames.pose_difference(T_s1_w0, T)[0] < 1e-3


def test_a_matrix_beyond_rounding_is_refused_with_its_measured_defect():
    data = copy.deepcopy(EXAMPLE)
    data["T_s1_w0"] = _rounded(data["T_s1_w0"], 6)
    data["T_s1_w0"][0][1] += 0.003
    R = np.array(data["T_s1_w0"])[:3, :3]
    defect = np.max(np.abs(R.T @ R - np.eye(3)))  # about 0.003, depending on the rest of the matrix
    assert 0.002 < defect < 0.004
    with pytest.raises(NotARotation, match=rf"T_s1_w0: .*\|R\^T R - I\| = {defect:.3g}, more than rounding"):
        parse_record(data)


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
