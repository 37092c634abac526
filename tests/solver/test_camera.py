import cv2
import numpy as np
import pytest

from monoguide.solver.camera import PAPER_CAMERA, CameraModel
from monoguide.solver.errors import MissingKey, RecordError, UnknownKey


def _grid(cam: CameraModel, n: int = 60) -> np.ndarray:
    u, v = np.meshgrid(np.linspace(-0.5, cam.width - 0.5, n), np.linspace(-0.5, cam.height - 0.5, n))
    return np.stack([u.ravel(), v.ravel()], axis=1)


def test_projection_matches_opencv():
    rng = np.random.default_rng(10)
    pts = np.column_stack([rng.uniform(-400, 400, 200), rng.uniform(-350, 350, 200), rng.uniform(500, 900, 200)])
    ours = PAPER_CAMERA.project(pts)
    ref, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), PAPER_CAMERA.K, PAPER_CAMERA.dist_coeffs)
    np.testing.assert_allclose(ours, ref.reshape(-1, 2), atol=1e-9)


def test_undistort_round_trip_over_whole_image_to_1e_10_px():
    pixels = _grid(PAPER_CAMERA)
    xy = PAPER_CAMERA.undistort_pixels(pixels)
    back = PAPER_CAMERA.normalized_to_pixels(xy)
    assert np.max(np.abs(back - pixels)) < 1e-10
    rays = PAPER_CAMERA.pixels_to_rays(pixels)
    np.testing.assert_allclose(np.linalg.norm(rays, axis=1), 1.0, atol=1e-15)
    np.testing.assert_allclose(PAPER_CAMERA.project(rays * 700.0), pixels, atol=1e-8)


def test_undistort_strong_lens_matches_opencv():
    cam = CameraModel(800, 600, 600.0, 610.0, 401.0, 297.0, k1=-0.3, k2=0.1, p1=0.001, p2=-0.002)
    pixels = _grid(cam, 30)
    ours = cam.undistort_pixels(pixels)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15)
    ref = cv2.undistortPoints(pixels.reshape(-1, 1, 2), cam.K, cam.dist_coeffs, R=None, P=None, criteria=criteria)
    # OpenCV's fixed-point iteration converges slowly in the corners of a strong lens: 1e-6 is its limit.
    np.testing.assert_allclose(ours, ref.reshape(-1, 2), atol=1e-6)
    np.testing.assert_allclose(cam.normalized_to_pixels(ours), pixels, atol=1e-9)


def test_analytic_jacobian_matches_finite_differences():
    rng = np.random.default_rng(11)
    pts = np.column_stack([rng.uniform(-400, 400, 30), rng.uniform(-350, 350, 30), rng.uniform(500, 900, 30)])
    _, J = PAPER_CAMERA.project_with_jacobian(pts)
    h = 1e-4
    for k in range(3):
        d = np.zeros(3)
        d[k] = h
        num = (PAPER_CAMERA.project(pts + d) - PAPER_CAMERA.project(pts - d)) / (2 * h)
        np.testing.assert_allclose(J[:, :, k], num, rtol=1e-6, atol=1e-7)


@pytest.mark.parametrize(
    ("change", "fragment"),
    [({"fx": "abc"}, "camera.fx"), ({"fy": float("nan")}, "camera.fy"), ({"width": -5}, "image size"),
     ({"fx": -1.0}, "focal")],
)
def test_from_dict_names_the_bad_key(change, fragment):
    values = PAPER_CAMERA.as_dict() | change
    with pytest.raises(RecordError, match=fragment):
        CameraModel.from_dict(values)


def test_from_dict_missing_key():
    values = PAPER_CAMERA.as_dict()
    del values["cx"]
    with pytest.raises(RecordError, match=r"camera\.cx: missing"):
        CameraModel.from_dict(values)


@pytest.mark.parametrize("key", ["k1", "k2", "p1", "p2"])
def test_from_dict_requires_every_distortion_coefficient(key):
    """No silent zero: a camera without k1 solved 2.7 mm off on the old reader."""
    values = PAPER_CAMERA.as_dict()
    del values[key]
    with pytest.raises(MissingKey, match=rf"camera\.{key}: missing"):
        CameraModel.from_dict(values)


def test_from_dict_refuses_an_unknown_key_naming_the_closest():
    values = PAPER_CAMERA.as_dict() | {"cxx": 1200.0}
    with pytest.raises(UnknownKey, match=r"intrinsics: unknown key 'cxx'; did you mean cx\?"):
        CameraModel.from_dict(values, where="intrinsics")


def test_from_dict_refuses_a_fractional_image_size():
    with pytest.raises(RecordError, match=r"camera\.width: expected a whole number"):
        CameraModel.from_dict(PAPER_CAMERA.as_dict() | {"width": 2456.5})
