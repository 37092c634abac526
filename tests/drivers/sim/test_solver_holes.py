"""Hole centres against the renderer's ground truth (seeded): accuracy per condition, perspective
correction, selection among clutter, every failure code, colour and 16-bit input."""

import math
from dataclasses import replace

import cv2
import numpy as np
import pytest

from monoguide.drivers.sim.hole_renderer import (
    Glare,
    HoleSpec,
    PartEdge,
    RenderSettings,
    defocus_for_depth_of_field,
    render_expected_image,
    render_view,
    scatter_clutter,
)
from monoguide.solver import frames
from monoguide.solver.camera import PAPER_CAMERA, CameraModel
from monoguide.solver.ellipse import Ellipse, fit_ellipse
from monoguide.solver.errors import (
    BadImage,
    FeatureNotFound,
    HoleAmbiguous,
    HoleCutByBorder,
    HoleNotFound,
    ImageSaturated,
    LowContrast,
)
from monoguide.solver.hole_edges import bit_depth_of
from monoguide.solver.holes import find_holes, measure_hole, perspective_correction

CROP = 360


def _pose(tilt_deg: float = 0.0, axis_deg: float = 0.0) -> np.ndarray:
    """Camera 650 mm above the sheet z = 0, looking down, tilted by ``tilt_deg`` about an in-plane axis."""
    a = math.radians(axis_deg)
    R = frames.rotvec_to_matrix(math.radians(tilt_deg) * np.array([math.cos(a), math.sin(a), 0.0]))
    return frames.make_T(np.diag([1.0, -1.0, -1.0]) @ R, np.array([0.0, 0.0, 650.0]))


def _crop_camera(u: float, v: float, size: int = CROP) -> tuple[CameraModel, np.ndarray]:
    """The part of the paper camera's 2456 x 2058 frame around full-frame pixel (u, v): same lens,
    principal point moved (distortion lives in normalised coordinates, so the crop is exact)."""
    x0, y0 = int(u) - size // 2, int(v) - size // 2
    return replace(PAPER_CAMERA, width=size, height=size, cx=PAPER_CAMERA.cx - x0, cy=PAPER_CAMERA.cy - y0), \
        np.array([x0, y0], dtype=float)


def _on_sheet(camera: CameraModel, T_c_w: np.ndarray, pixel) -> np.ndarray:
    ray = camera.pixels_to_rays(np.asarray(pixel, float)[None])[0]
    T_w_c = frames.invert(T_c_w)
    origin, direction = T_w_c[:3, 3], T_w_c[:3, :3] @ ray
    return origin - origin[2] / direction[2] * direction


def _scene(seed: int, radius_mm: float, settings: RenderSettings, tilt_deg: float = 4.0, clutter: bool = True,
           at=(1900.0, 1500.0)):
    """One hole at full-frame pixel ``at`` seen through a crop camera; returns camera, pose, hole, view."""
    rng = np.random.default_rng(seed)
    camera, _ = _crop_camera(*at)
    T = _pose(tilt_deg, rng.uniform(0, 360))
    center = _on_sheet(camera, T, (CROP / 2 + rng.uniform(-3, 3), CROP / 2 + rng.uniform(-3, 3)))
    hole = HoleSpec(center, radius_mm)
    others = scatter_clutter(hole, rng, count=2, gap_mm=(4.0, 8.0)) if clutter else []
    view = render_view(camera, T, [hole], settings, rng, others)
    return camera, T, hole, view


def _radius_px(camera: CameraModel, T: np.ndarray, hole: HoleSpec) -> float:
    depth = (T[:3, :3] @ hole.center_w + T[:3, 3])[2]
    return hole.radius_mm * math.sqrt(camera.fx * camera.fy) / depth


CONDITIONS = {
    # name: (settings, radius mm, RMS bound px, max bound px) over 6 seeds, after perspective correction
    "strong, sharp, quiet": (RenderSettings(blur_sigma_px=0.7, noise_sigma=1.5), 6.0, 0.012, 0.025),
    "strong, blurred, noisy": (RenderSettings(blur_sigma_px=1.5, noise_sigma=4.0), 6.0, 0.03, 0.06),
    "weak contrast, noisy": (RenderSettings(sheet_grey=125, hole_grey=80, noise_sigma=3.0), 8.0, 0.045, 0.09),
    "small hole 4 mm": (RenderSettings(blur_sigma_px=1.2, noise_sigma=3.0), 4.0, 0.03, 0.06),
    "large hole 10 mm, uneven light": (RenderSettings(light_gradient=0.25, noise_sigma=3.0), 10.0, 0.025, 0.05),
}


@pytest.mark.parametrize("name", list(CONDITIONS))
def test_accuracy_per_condition_against_the_projected_3d_centre(name):
    settings, radius, rms_bound, max_bound = CONDITIONS[name]
    errors = []
    for seed in range(6):
        camera, T, hole, view = _scene(seed, radius, settings)
        r_px = _radius_px(camera, T, hole)
        found = measure_hole(view.image, view.centers_px[0] + (4.0, -3.0), r_px)
        correction = perspective_correction(camera, T, hole.center_w, hole.normal_w, hole.radius_mm)
        errors.append(np.hypot(*(found.center - correction - view.centers_px[0])))
        assert abs(found.mean_radius / r_px - 1.0) < 0.03
    errors = np.array(errors)
    assert math.sqrt(np.mean(errors**2)) < rms_bound, errors
    assert errors.max() < max_bound, errors


def test_paper_pipeline_alone_is_sub_pixel_accurate():
    errors = []
    for seed in range(6):
        camera, T, hole, view = _scene(seed, 7.0, RenderSettings(noise_sigma=2.5))
        found = measure_hole(view.image, view.centers_px[0], _radius_px(camera, T, hole), photometric=False)
        correction = perspective_correction(camera, T, hole.center_w, hole.normal_w, hole.radius_mm)
        errors.append(np.hypot(*(found.center - correction - view.centers_px[0])))
    assert math.sqrt(np.mean(np.square(errors))) < 0.03


def test_perspective_correction_matches_the_renderer_ground_truth():
    # A large hole, steep view, image corner: noise-free 16-bit image, so the centre of the imaged ellipse
    # is measured to ~1e-3 px and the difference from the projected 3-D centre is the correction's.
    camera, _ = _crop_camera(2250.0, 1850.0, size=200)
    T = _pose(12.0, 40.0)
    hole = HoleSpec(_on_sheet(camera, T, (100.0, 100.0)), 10.0)
    image = render_expected_image(camera, T, [hole], RenderSettings(light_gradient=0.0))
    image16 = np.round(image * 257.0).astype(np.uint16)
    truth = camera.project((T[:3, :3] @ hole.center_w + T[:3, 3])[None])[0]
    found = measure_hole(image16, truth, _radius_px(camera, T, hole))
    correction = perspective_correction(camera, T, hole.center_w, hole.normal_w, hole.radius_mm)
    assert np.hypot(*correction) > 0.04  # this geometry shifts the ellipse centre by ~0.05 px
    np.testing.assert_allclose(found.center - truth, correction, atol=0.004)
    # an approximate pose (1 mm, 0.2 deg off) gives nearly the same correction: one iteration is enough
    T_approx = frames.make_T(frames.rotvec_to_matrix(np.radians([0.2, 0.0, 0.0])) @ T[:3, :3], T[:3, 3] + 1.0)
    approx = perspective_correction(camera, T_approx, hole.center_w, hole.normal_w, hole.radius_mm)
    np.testing.assert_allclose(approx, correction, atol=0.005)


def test_perspective_correction_without_distortion_is_the_conic_centre():
    # Pinhole: the rim projects to the conic C = H^-T Q H^-1 (Q the circle in the plane, H the homography).
    camera = CameraModel(2456, 2058, 2421.4, 2419.7, 1238.0, 971.4)
    T = _pose(15.0, 70.0)
    center = np.array([180.0, -120.0, 0.0])
    radius = 9.0
    H = camera.K @ np.column_stack([T[:3, 0], T[:3, 1], T[:3, :3] @ center + T[:3, 3]])
    Q = np.diag([1.0, 1.0, -radius**2])
    Hi = np.linalg.inv(H)
    C = Hi.T @ Q @ Hi
    conic_center = np.linalg.solve(C[:2, :2], -C[:2, 2])
    projected = camera.project((T[:3, :3] @ center + T[:3, 3])[None])[0]
    correction = perspective_correction(camera, T, center, (0.0, 0.0, 1.0), radius)
    np.testing.assert_allclose(correction, conic_center - projected, atol=1e-6)
    assert np.hypot(*correction) > 0.05


def test_pick_the_expected_hole_among_clutter_of_other_sizes():
    camera, _ = _crop_camera(1200.0, 900.0, size=480)
    T = _pose(3.0, 10.0)
    for seed in range(4):
        rng = np.random.default_rng(100 + seed)
        hole = HoleSpec(_on_sheet(camera, T, (240.0, 240.0)), 6.0)
        clutter = scatter_clutter(hole, rng, count=4, radius_factors=(0.55, 0.7, 1.45, 1.8), gap_mm=(3.0, 10.0))
        view = render_view(camera, T, [hole], RenderSettings(noise_sigma=3.0), rng, clutter)
        r_px = _radius_px(camera, T, hole) * rng.uniform(0.95, 1.05)
        expected = view.centers_px[0] + rng.normal(0, 10.0, 2)
        found = measure_hole(view.image, expected, r_px, roi=(0, 0, 480, 480), max_offset_px=200.0)
        assert np.hypot(*(found.center - view.centers_px[0])) < 0.1
        everything = find_holes(view.image)
        assert len(everything) == 1 + len(clutter)


def test_two_holes_of_the_expected_size_are_ambiguous():
    camera, _ = _crop_camera(1200.0, 900.0)
    T = _pose()
    a = HoleSpec(_on_sheet(camera, T, (140.0, 180.0)), 5.0)
    b = HoleSpec(_on_sheet(camera, T, (225.0, 180.0)), 5.0)
    view = render_view(camera, T, [a, b], RenderSettings(), np.random.default_rng(0))
    r_px = _radius_px(camera, T, a)
    with pytest.raises(HoleAmbiguous, match=r"hole expected at \(180\.0, 180\.0\) r=18\.\d px: 2 candidates"):
        measure_hole(view.image, (180.0, 180.0), r_px)
    # a tighter search radius around the right place resolves it
    found = measure_hole(view.image, view.centers_px[0] + 3.0, r_px, max_offset_px=30.0)
    assert np.hypot(*(found.center - view.centers_px[0])) < 0.05


def test_hole_not_found_on_blank_sheet_and_with_wrong_size():
    camera, _ = _crop_camera(1200.0, 900.0)
    blank = render_view(camera, _pose(), [], RenderSettings(), np.random.default_rng(1)).image
    with pytest.raises(HoleNotFound, match=r"hole expected at \(180\.0, 170\.0\) r=20\.0 px"):
        measure_hole(blank, (180.0, 170.0), 20.0)
    _, T, hole, view = _scene(2, 6.0, RenderSettings(), clutter=False)
    with pytest.raises(HoleNotFound, match="seen"):
        measure_hole(view.image, view.centers_px[0], 2.0 * _radius_px(camera, T, hole), radius_tol=0.25)


def test_hole_cut_by_the_image_border():
    camera, _ = _crop_camera(1200.0, 900.0)
    T = _pose()
    hole = HoleSpec(_on_sheet(camera, T, (8.0, 180.0)), 6.0)
    view = render_view(camera, T, [hole], RenderSettings(), np.random.default_rng(3))
    assert not view.in_view[0]
    with pytest.raises(HoleCutByBorder, match="image border"):
        measure_hole(view.image, view.centers_px[0], _radius_px(camera, T, hole))
    assert find_holes(view.image) == []


@pytest.mark.parametrize(
    "settings",
    [RenderSettings(sheet_grey=100.0, hole_grey=92.0), RenderSettings(blur_sigma_px=4.5)],
    ids=["faint", "blurred"],
)
def test_low_contrast_and_heavy_blur_are_refused(settings):
    camera, T, hole, view = _scene(4, 7.0, settings, clutter=False)
    with pytest.raises(LowContrast, match=r"contrast|blurred|gradient"):
        measure_hole(view.image, view.centers_px[0], _radius_px(camera, T, hole))


def test_saturated_image_is_refused():
    camera, T, hole, view = _scene(5, 7.0, RenderSettings(exposure=1.8), clutter=False)
    with pytest.raises(ImageSaturated, match="saturated"):
        measure_hole(view.image, view.centers_px[0], _radius_px(camera, T, hole))
    white = np.full((200, 200), 255, np.uint8)
    with pytest.raises(ImageSaturated):
        measure_hole(white, (100.0, 100.0), 20.0)


def test_glare_and_part_edge_nearby_do_not_move_the_centre():
    camera, _ = _crop_camera(1000.0, 800.0, size=400)
    T = _pose(2.0)
    hole = HoleSpec(_on_sheet(camera, T, (200.0, 200.0)), 6.0)
    edge_point = _on_sheet(camera, T, (200.0, 300.0))
    settings = RenderSettings(noise_sigma=2.0, glare=Glare((320.0, 120.0), 40.0, 80.0),
                              part_edge=PartEdge(edge_point, (0.0, -1.0, 0.0)))
    errors = []
    for seed in range(4):
        view = render_view(camera, T, [hole], settings, np.random.default_rng(seed))
        found = measure_hole(view.image, view.centers_px[0] + 5.0, _radius_px(camera, T, hole))
        correction = perspective_correction(camera, T, hole.center_w, hole.normal_w, hole.radius_mm)
        errors.append(np.hypot(*(found.center - correction - view.centers_px[0])))
    assert max(errors) < 0.04, errors


@pytest.mark.parametrize("kind", ["bgr", "bgra", "grey3d", "uint16"])
def test_colour_and_16_bit_images_are_converted(kind):
    camera, T, hole, view = _scene(6, 7.0, RenderSettings(), clutter=False)
    grey = view.image
    image = {
        "bgr": cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR),
        "bgra": cv2.cvtColor(grey, cv2.COLOR_GRAY2BGRA),
        "grey3d": grey[:, :, None],
        "uint16": grey.astype(np.uint16) * 257,
    }[kind]
    r_px = _radius_px(camera, T, hole)
    reference = measure_hole(grey, view.centers_px[0], r_px)
    converted = measure_hole(image, view.centers_px[0], r_px)
    np.testing.assert_allclose(converted.center, reference.center, atol=1e-3)


@pytest.mark.parametrize(
    ("image", "message"),
    [
        (np.zeros((100, 100), np.float32), "dtype"),
        (np.zeros((100,), np.uint8), "shape"),
        (np.zeros((0, 0), np.uint8), "empty"),
        (np.zeros((100, 100, 2), np.uint8), "shape"),
        ([[1, 2], [3, 4]], "numpy array"),
    ],
)
def test_bad_images_are_refused(image, message):
    with pytest.raises(BadImage, match=message):
        find_holes(image)
    with pytest.raises(BadImage, match=message):
        measure_hole(image, (50.0, 50.0), 10.0)


def test_full_frame_finds_every_in_view_hole_most_plausible_first():
    T = _pose(2.0)
    rng = np.random.default_rng(8)
    pixels = [(300.0, 250.0), (1240.0, 970.0), (2150.0, 1800.0), (600.0, 1700.0)]
    holes = [HoleSpec(_on_sheet(PAPER_CAMERA, T, p), r) for p, r in zip(pixels, (4.0, 10.0, 6.0, 8.0), strict=True)]
    settings = RenderSettings(noise_sigma=3.0, light_gradient=0.25, glare=Glare((1700.0, 500.0), 60.0, 80.0))
    view = render_view(PAPER_CAMERA, T, holes, settings, rng)
    found = find_holes(view.image)
    assert len(found) == len(holes)
    for truth in view.centers_px:
        assert min(np.hypot(*(h.center - truth)) for h in found) < 0.1
    scores = [h.score for h in found]
    assert scores == sorted(scores, reverse=True)
    in_roi = find_holes(view.image, roi=(1100, 800, 300, 300))
    assert len(in_roi) == 1 and np.hypot(*(in_roi[0].center - view.centers_px[1])) < 0.1


def test_ellipse_fit_recovers_an_exact_ellipse_and_refuses_too_few_points():
    truth = Ellipse(center=np.array([312.25, 87.5]), axes=np.array([25.0, 19.0]), angle_deg=33.0)
    fitted = fit_ellipse(truth.points(50))
    np.testing.assert_allclose(fitted.center, truth.center, atol=1e-9)
    np.testing.assert_allclose(fitted.axes, truth.axes, atol=1e-9)
    assert fitted.angle_deg == pytest.approx(33.0, abs=1e-7)
    assert np.max(np.abs(fitted.distances(truth.points(17)))) < 1e-9
    with pytest.raises(FeatureNotFound, match="at least 6 points"):
        fit_ellipse(truth.points(5))


@pytest.mark.parametrize(("pixel_format", "bits"), [("Mono10", 10), ("Mono12", 12), ("Mono12p", 12), ("Mono16", 16)])
def test_mono10_and_mono12_frames_are_scaled_by_their_bit_depth(pixel_format, bits):
    camera, T, hole, view = _scene(7, 7.0, RenderSettings(noise_sigma=2.0), clutter=False)
    deep = np.round(view.image.astype(float) * ((2**bits - 1) / 255.0)).astype(np.uint16)
    r_px = _radius_px(camera, T, hole)
    found = measure_hole(deep, view.centers_px[0], r_px, bit_depth=bit_depth_of(pixel_format))
    correction = perspective_correction(camera, T, hole.center_w, hole.normal_w, hole.radius_mm)
    assert np.hypot(*(found.center - correction - view.centers_px[0])) < 0.05
    assert found.contrast == pytest.approx(150.0, rel=0.15)  # the rendered 180 - 30, on the 0-255 scale


def test_bit_depth_refuses_what_it_cannot_be():
    image = np.full((50, 50), 5000, np.uint16)
    with pytest.raises(BadImage, match=r"value of 5000 in a 12-bit image"):
        find_holes(image, bit_depth=12)
    with pytest.raises(BadImage, match="Mono8, Mono10"):
        bit_depth_of("RGB8")
    with pytest.raises(BadImage, match=r"8\.\.16"):
        find_holes(image, bit_depth=7)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_sensor_noise_alone_is_no_hole(seed):
    rng = np.random.default_rng(seed)
    noise = np.clip(rng.normal(128.0, 12.0 * (seed + 1), (700, 900)), 0, 255).astype(np.uint8)
    assert find_holes(noise) == []
    with pytest.raises(HoleNotFound):
        measure_hole(noise, (450.0, 350.0), 15.0, max_offset_px=300.0)


def test_a_roi_inside_the_hole_finds_it_by_its_centre():
    *_, view = _scene(9, 7.0, RenderSettings(), clutter=False)
    u, v = view.centers_px[0]
    [found] = find_holes(view.image, roi=(round(u) - 5, round(v) - 5, 10, 10))
    assert np.hypot(*(found.center - view.centers_px[0])) < 0.1
    assert find_holes(view.image, roi=(round(u) + 6, round(v) - 5, 10, 10)) == []


def _look_at(eye: np.ndarray, target: np.ndarray, roll: float) -> np.ndarray:
    """``T_c_w`` of a camera at ``eye`` looking at ``target``, turned by ``roll`` rad about its axis."""
    z = (target - eye) / np.linalg.norm(target - eye)
    x = np.cross([1.0, 0.0, 0.0] if abs(z[0]) < 0.9 else [0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    R_w_c = np.column_stack([x, np.cross(z, x), z]) @ frames.rotvec_to_matrix(np.array([0.0, 0.0, roll]))
    return frames.make_T(R_w_c.T, -R_w_c.T @ eye)


@pytest.mark.parametrize("tilt_deg", [30.0, 40.0])
def test_oblique_views_over_the_depth_range_keep_their_accuracy(tilt_deg):
    # The planned layout: line of sight 30-40 deg from the sheet normal, depth 550-800 mm, a lens focused at
    # 652 mm whose blur circle is 2 px at 550 and 800 mm; the hole anywhere in the full frame.
    focus, aperture = defocus_for_depth_of_field(math.sqrt(PAPER_CAMERA.fx * PAPER_CAMERA.fy), 550.0, 800.0, 2.0)
    corrected, raw = [], []
    for seed in range(8):
        rng = np.random.default_rng(200 + seed)
        azimuth, tilt = rng.uniform(0, 2 * math.pi), math.radians(tilt_deg)
        sight = np.array([math.sin(tilt) * math.cos(azimuth), math.sin(tilt) * math.sin(azimuth), math.cos(tilt)])
        hole = HoleSpec(np.zeros(3), rng.uniform(4.0, 10.0))
        aim = np.array([*rng.uniform(-150.0, 150.0, 2), 0.0])  # the hole off the image centre
        T = _look_at(rng.uniform(550.0, 800.0) * sight, aim, rng.uniform(0, 2 * math.pi))
        full_frame = PAPER_CAMERA.project(T[:3, 3][None])[0]
        camera, _ = _crop_camera(*full_frame, size=300)
        settings = RenderSettings(noise_sigma=2.0, sheet_grey=170.0, hole_grey=40.0,
                                  focus_distance_mm=focus, aperture_mm=aperture)
        view = render_view(camera, T, [hole], settings, rng, scatter_clutter(hole, rng, count=2))
        r_px = _radius_px(camera, T, hole) * math.sqrt(math.cos(tilt))  # foreshortened
        found = measure_hole(view.image, view.centers_px[0] + rng.normal(0.0, 5.0, 2), r_px)
        T_approx = frames.make_T(frames.rotvec_to_matrix(np.radians([0.2, -0.1, 0.1])) @ T[:3, :3], T[:3, 3] + 0.6)
        correction = perspective_correction(camera, T_approx, hole.center_w, hole.normal_w, hole.radius_mm)
        corrected.append(np.hypot(*(found.center - correction - view.centers_px[0])))
        raw.append(np.hypot(*(found.center - view.centers_px[0])))
        assert abs(found.mean_radius / r_px - 1.0) < 0.05
    corrected = np.array(corrected)
    assert math.sqrt(np.mean(corrected**2)) < 0.02, corrected
    assert corrected.max() < 0.04, corrected
    assert math.sqrt(np.mean(np.square(raw))) > 0.05  # the conic-centre bias the correction removes


@pytest.mark.parametrize(("tilt_deg", "seed"), [(30.0, 0), (40.0, 1), (45.0, 2)])
def test_perspective_correction_is_exact_for_oblique_circles(tilt_deg, seed):
    # Noise-free 16-bit renders through the distorted lens: what is left after the correction is the
    # detector's own bias, ~1e-3 px, while the conic-centre bias itself is 0.1-0.4 px.
    rng = np.random.default_rng(300 + seed)
    azimuth, tilt = rng.uniform(0, 2 * math.pi), math.radians(tilt_deg)
    sight = np.array([math.sin(tilt) * math.cos(azimuth), math.sin(tilt) * math.sin(azimuth), math.cos(tilt)])
    hole = HoleSpec(np.zeros(3), 9.0)
    T = _look_at(600.0 * sight, np.array([*rng.uniform(-200.0, 200.0, 2), 0.0]), rng.uniform(0, 2 * math.pi))
    camera, _ = _crop_camera(*PAPER_CAMERA.project(T[:3, 3][None])[0], size=200)
    image = render_expected_image(camera, T, [hole], RenderSettings(light_gradient=0.0))
    truth = camera.project(T[:3, 3][None])[0]
    found = measure_hole(np.round(image * 257.0).astype(np.uint16), truth,
                         _radius_px(camera, T, hole) * math.sqrt(math.cos(tilt)))
    correction = perspective_correction(camera, T, hole.center_w, hole.normal_w, hole.radius_mm)
    assert np.hypot(*correction) > 0.08
    np.testing.assert_allclose(found.center - truth, correction, atol=0.004)


def test_a_refused_hole_leaves_no_frame_behind_in_a_reference_cycle():
    """The finder's refusal (glare on the hole's rim: a blob refused on the way) holds none of the search's frames in
    a reference cycle: once the service has let go of the error's traceback, the images and arrays of the search are
    freed at once, not at the garbage collector's next pass (a failed cycle's 20-30 MB, until then)."""
    import gc
    import types

    from monoguide.daemon.errors import drop_tracebacks

    camera, T, hole, view = _scene(9, 7.0, RenderSettings(), clutter=True)
    glare = Glare(center_px=(float(view.centers_px[0][0]), float(view.centers_px[0][1])), sigma_px=40.0,
                  peak_grey=400.0)
    _, _, _, view = _scene(9, 7.0, RenderSettings(glare=glare), clutter=True)
    gc.collect()
    gc.disable()
    gc.set_debug(gc.DEBUG_SAVEALL)
    try:
        with pytest.raises(ImageSaturated) as refused:
            measure_hole(view.image, view.centers_px[0], _radius_px(camera, T, hole))
        error = refused.value
        drop_tracebacks(error)
        del refused
        gc.collect()
        frames_held = [o for o in gc.garbage if isinstance(o, types.FrameType)]
        images = sum(v.nbytes for f in frames_held for v in f.f_locals.values() if isinstance(v, np.ndarray))
        assert not frames_held, f"{len(frames_held)} frames in a reference cycle, holding {images} bytes of arrays"
        assert "saturated" in error.message  # the reason stays
    finally:
        gc.set_debug(0)
        gc.garbage.clear()
        gc.enable()
