"""The hole renderer: exact rims, exact truth, photometry as configured."""

import math
import time
from dataclasses import replace

import numpy as np
import pytest

from monoguide.drivers.sim.hole_renderer import (
    Glare,
    HoleSpec,
    PartEdge,
    RenderSettings,
    blur_sigma_at,
    defocus_for_depth_of_field,
    hole_coverage,
    render_expected_image,
    render_view,
    scatter_clutter,
)
from monoguide.solver import frames
from monoguide.solver.camera import PAPER_CAMERA, CameraModel

LOOK_DOWN = frames.make_T(np.diag([1.0, -1.0, -1.0]), np.array([0.0, 0.0, 650.0]))
PINHOLE = CameraModel(320, 240, 2421.4, 2419.7, 160.3, 120.1)


def _tilted(tilt_deg: float, axis_deg: float = 30.0) -> np.ndarray:
    a = math.radians(axis_deg)
    R = frames.rotvec_to_matrix(math.radians(tilt_deg) * np.array([math.cos(a), math.sin(a), 0.0]))
    return frames.make_T(np.diag([1.0, -1.0, -1.0]) @ R, np.array([0.0, 0.0, 650.0]))


def _centroid(box, coverage):
    x0, y0, x1, y1 = box
    vv, uu = np.mgrid[y0:y1, x0:x1]
    return np.array([(coverage * uu).sum(), (coverage * vv).sum()]) / coverage.sum()


@pytest.mark.parametrize("seed", range(4))
def test_frontal_disc_coverage_has_exact_area_and_centroid(seed):
    # Frontal view through a pinhole: the image of the circle is a circle of radius f r / z around the
    # projected centre, so the coverage's area and centroid are known in closed form.
    rng = np.random.default_rng(seed)
    center = np.array([rng.uniform(-3, 3), rng.uniform(-3, 3), 0.0])
    radius = rng.uniform(4.0, 10.0)
    box, coverage = hole_coverage(PINHOLE, LOOK_DOWN, HoleSpec(center, radius))
    truth = PINHOLE.project((LOOK_DOWN[:3, :3] @ center + LOOK_DOWN[:3, 3])[None])[0]
    area = math.pi * (radius * PINHOLE.fx / 650.0) * (radius * PINHOLE.fy / 650.0)
    assert coverage.sum() / area - 1.0 == pytest.approx(0.0, abs=2e-4)
    np.testing.assert_allclose(_centroid(box, coverage), truth, atol=1e-3)


def test_supersampled_band_converges_on_a_tilted_distorted_rim():
    camera = replace(PAPER_CAMERA, width=400, height=400, cx=PAPER_CAMERA.cx - 1900, cy=PAPER_CAMERA.cy - 1500)
    T = _tilted(8.0)
    hole = HoleSpec(np.array([200.0, -160.0, 0.0]), 9.0)
    T_far = T.copy()
    pixel = camera.project((T_far[:3, :3] @ hole.center_w + T_far[:3, 3])[None])[0]
    assert camera.in_image(pixel[None])[0]
    box4, cov4 = hole_coverage(camera, T, hole, supersample=4)
    box32, cov32 = hole_coverage(camera, T, hole, supersample=32)
    assert box4 == box32
    assert np.max(np.abs(cov4 - cov32)) < 0.015
    assert np.abs(_centroid(box4, cov4) - _centroid(box32, cov32)).max() < 1e-3
    assert abs(cov4.sum() - cov32.sum()) < 1e-3 * cov32.sum()


def test_truth_is_the_projection_of_the_3d_centre_and_in_view_flags_cut_holes():
    holes = [HoleSpec(np.array([0.0, 0.0, 0.0]), 6.0), HoleSpec(np.array([-42.0, 0.0, 0.0]), 6.0),
             HoleSpec(np.array([200.0, 0.0, 0.0]), 6.0)]
    view = render_view(PINHOLE, LOOK_DOWN, holes, RenderSettings(), np.random.default_rng(0))
    expected = PINHOLE.project(frames.transform_points(LOOK_DOWN, np.array([h.center_w for h in holes])))
    np.testing.assert_allclose(view.centers_px, expected, atol=1e-12)
    # 42 mm left of the centre is 156 px: the rim (22 px) crosses x = -0.5; 200 mm is outside entirely
    assert view.in_view.tolist() == [True, False, False]
    assert view.image.dtype == np.uint8 and view.image.shape == (240, 320)


def test_photometry_levels_noise_and_saturation():
    settings = RenderSettings(noise_sigma=3.0, light_gradient=0.0, blur_sigma_px=1.0)
    hole = HoleSpec(np.zeros(3), 8.0)
    view = render_view(PINHOLE, LOOK_DOWN, [hole], settings, np.random.default_rng(1))
    u, v = np.round(view.centers_px[0]).astype(int)
    sheet = view.image[:40, :].astype(float)
    assert sheet.mean() == pytest.approx(180.0, abs=0.3)
    assert sheet.std() == pytest.approx(math.sqrt(9.0 + 1.0 / 12.0), rel=0.05)
    assert view.image[v - 5 : v + 5, u - 5 : u + 5].mean() == pytest.approx(30.0, abs=1.0)
    bright = render_view(PINHOLE, LOOK_DOWN, [hole], replace(settings, exposure=1.6), np.random.default_rng(1))
    assert np.mean(bright.image[:40, :] == 255) > 0.99


def test_light_gradient_spans_the_frame():
    settings = RenderSettings(noise_sigma=0.0, light_gradient=0.25, light_direction_deg=0.0)
    image = render_expected_image(PINHOLE, LOOK_DOWN, [], settings)
    assert image[:, 0].mean() == pytest.approx(180.0 * 0.75, rel=1e-3)
    assert image[:, -1].mean() == pytest.approx(180.0 * 1.25, rel=1e-3)


def test_part_edge_and_glare():
    edge = PartEdge(point_w=(0.0, 10.0, 0.0), outward_w=(0.0, 1.0, 0.0), beyond_grey=60.0)
    settings = RenderSettings(noise_sigma=0.0, light_gradient=0.0, part_edge=edge,
                              glare=Glare(center_px=(60.0, 180.0), sigma_px=10.0, peak_grey=50.0))
    image = render_expected_image(PINHOLE, LOOK_DOWN, [], settings)
    # y = 10 mm on the part is 37 px above the principal point (the camera's y axis points the other way)
    v_edge = PINHOLE.cy - 10.0 * PINHOLE.fy / 650.0
    column = image[:, 250]
    assert column[int(v_edge) - 5] == pytest.approx(60.0, abs=0.5)
    assert column[int(v_edge) + 5] == pytest.approx(180.0, abs=0.5)
    crossing = np.interp(120.0, column[int(v_edge) - 4 : int(v_edge) + 5], np.arange(int(v_edge) - 4, int(v_edge) + 5))
    assert crossing == pytest.approx(v_edge, abs=0.1)
    # the glare adds its peak (less the blur: sigma^2 / (sigma^2 + 1)) on the sheet
    assert image[180, 60] == pytest.approx(180.0 + 50.0 * 100.0 / 101.0, abs=0.5)


def test_same_seed_same_image():
    holes = [HoleSpec(np.zeros(3), 7.0)]
    a = render_view(PINHOLE, LOOK_DOWN, holes, RenderSettings(), np.random.default_rng(5)).image
    b = render_view(PINHOLE, LOOK_DOWN, holes, RenderSettings(), np.random.default_rng(5)).image
    np.testing.assert_array_equal(a, b)


def test_clutter_does_not_overlap_and_has_other_sizes():
    hole = HoleSpec(np.zeros(3), 6.0)
    clutter = scatter_clutter(hole, np.random.default_rng(2), count=4)
    assert len(clutter) == 4
    everything = [hole, *clutter]
    for i, a in enumerate(everything):
        for b in everything[i + 1 :]:
            assert np.linalg.norm(a.center_w - b.center_w) > a.radius_mm + b.radius_mm
    assert all(abs(c.radius_mm / hole.radius_mm - 1.0) > 0.3 for c in clutter)


def test_full_frame_renders_well_under_a_second():
    holes = [HoleSpec(np.array([x, y, 0.0]), 8.0) for x, y in ((0, 0), (100, 50), (-150, -100))]
    settings = RenderSettings(glare=Glare((1500.0, 700.0)), part_edge=PartEdge((0.0, 240.0, 0.0), (0.0, 1.0, 0.0)))
    render_view(PAPER_CAMERA, LOOK_DOWN, holes, settings, np.random.default_rng(0))  # warm-up
    start = time.perf_counter()
    view = render_view(PAPER_CAMERA, LOOK_DOWN, holes, settings, np.random.default_rng(0),
                       clutter=scatter_clutter(holes[0], np.random.default_rng(1)))
    assert time.perf_counter() - start < 1.0
    assert view.image.shape == (2058, 2456) and view.in_view.all()


def _rim_sigma(view_image: np.ndarray, center_px: np.ndarray, radius_px: float) -> float:
    """The Gaussian sigma of the rendered rim, fitted to its grey levels (pixel area adds 1/12 px^2)."""
    from monoguide.solver.ellipse import Ellipse
    from monoguide.solver.holes import measure_hole
    from monoguide.solver.rim_fit import refine_ellipse_photometric

    paper = measure_hole(np.round(view_image * 257.0).astype(np.uint16), center_px, radius_px, photometric=False)
    start = Ellipse(center=paper.center, axes=paper.axes, angle_deg=paper.angle_deg)
    _, sigma = refine_ellipse_photometric(view_image.astype(np.float32), start, paper.edge_width_px)
    return math.sqrt(max(sigma**2 - 1.0 / 12.0, 0.0))


@pytest.mark.parametrize("depth_mm", [450.0, 600.0, 900.0])
def test_defocus_grows_with_the_distance_from_the_focus_plane(depth_mm):
    focus, aperture = defocus_for_depth_of_field(PINHOLE.fx, 450.0, 900.0, circle_px=8.0)
    assert focus == pytest.approx(600.0)  # the harmonic mean of 450 and 900
    settings = RenderSettings(noise_sigma=0.0, light_gradient=0.0, blur_sigma_px=0.8,
                              focus_distance_mm=focus, aperture_mm=aperture)
    T = frames.make_T(np.diag([1.0, -1.0, -1.0]), np.array([0.0, 0.0, depth_mm]))
    hole = HoleSpec(np.zeros(3), 6.0 * depth_mm / 650.0)  # the same size in the image at every depth
    image = render_expected_image(PINHOLE, T, [hole], settings)
    truth = PINHOLE.project(T[:3, 3][None])[0]
    expected = 0.8 if depth_mm == 600.0 else math.hypot(0.8, 8.0 / 4.0)  # circle 8 px at both ends
    assert blur_sigma_at(depth_mm, settings, PINHOLE.fx) == pytest.approx(expected, rel=1e-9)
    assert _rim_sigma(image, truth, 6.0 * PINHOLE.fx / 650.0) == pytest.approx(expected, rel=0.05)


def test_a_tilted_sheet_is_sharp_at_the_focus_depth_and_blurred_away_from_it():
    T = _tilted(35.0, axis_deg=0.0)  # the sheet runs from near (top of the image) to far
    camera = replace(PINHOLE, width=900, height=700, cx=450.0, cy=350.0)
    pixels = [(450.0, 120.0), (450.0, 580.0)]
    holes = [HoleSpec(_on_sheet(camera, T, p), 5.0) for p in pixels]
    depths = [float((T[:3, :3] @ h.center_w + T[:3, 3])[2]) for h in holes]
    assert depths[1] - depths[0] > 60.0 or depths[0] - depths[1] > 60.0
    settings = RenderSettings(noise_sigma=0.0, light_gradient=0.0, blur_sigma_px=0.7,
                              focus_distance_mm=depths[0], aperture_mm=10.0)
    image = render_expected_image(camera, T, holes, settings)
    for hole, depth in zip(holes, depths, strict=True):
        truth = camera.project((T[:3, :3] @ hole.center_w + T[:3, 3])[None])[0]
        radius = 5.0 * camera.fx / depth * math.sqrt(math.cos(math.radians(35.0)))
        expected = float(blur_sigma_at(depth, settings, camera.fx))
        assert _rim_sigma(image, truth, radius) == pytest.approx(expected, rel=0.08)
    assert float(blur_sigma_at(depths[1], settings, camera.fx)) > 1.5 * 0.7


def test_without_an_aperture_the_blur_is_the_same_everywhere():
    holes = [HoleSpec(np.array([0.0, 0.0, 0.0]), 5.0)]
    plain = render_expected_image(PINHOLE, LOOK_DOWN, holes, RenderSettings())
    unfocused = render_expected_image(PINHOLE, LOOK_DOWN, holes, RenderSettings(focus_distance_mm=300.0))
    np.testing.assert_array_equal(plain, unfocused)
    with pytest.raises(ValueError, match="near < far"):
        defocus_for_depth_of_field(PINHOLE.fx, 900.0, 450.0)


def _on_sheet(camera: CameraModel, T_c_w: np.ndarray, pixel) -> np.ndarray:
    ray = camera.pixels_to_rays(np.asarray(pixel, float)[None])[0]
    T_w_c = frames.invert(T_c_w)
    origin, direction = T_w_c[:3, 3], T_w_c[:3, :3] @ ray
    return origin - origin[2] / direction[2] * direction
