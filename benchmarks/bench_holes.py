"""Hole-centre benchmark (issue 3). Prints tables; asserts nothing.

Seeded full-frame renders (Table 2 camera, 2456 x 2058) of the range a line sees: two featured holes of
radius 4-10 mm at ~650 mm with the sheet tilted up to 6 deg, each among three clutter holes of other
sizes, sometimes a part edge and a glare spot; blur sigma 0.7-1.5 px, noise sigma 1.5-4 grey levels,
light +-0-25 % across the frame, contrast strong / medium / weak. For each hole: the centre error of
``measure_hole`` (expected position off by ~15 px, radius by <=5 %) against the projection of the
3-D centre, raw and after ``perspective_correction`` from a pose off by 1 mm / 0.2 deg; recall and
wrong picks; the baseline a user writes first (Otsu, contours, cv2.fitEllipse, nearest of the right
size) on the same region; and the Cramér-Rao bound of the centre, sigma^2 (J^T J)^-1 with J the
derivative of the noise-free image w.r.t. the centre. Times on one core.

Oblique rows (issue 8): the planned layout tilts each camera so that its line of sight meets the sheet
30 or 40 deg from the normal, the hole near the image centre at a nominal standoff of 575-775 mm; the part
then deviates over the full envelope, +-50 mm and +-5 deg on every axis about a centre up to 0.8 m from
the hole, so the hole wanders in the image, its depth spans 550-800 mm and its viewing angle +-5 deg.
The camera is focused at 652 mm with the aperture that blurs 550 and 800 mm by a 2 px circle (thin lens,
on top of the lens blur). Same photometry, clutter, glare and edge draws; rendered through a 640 x 640
crop of the same lens (exact: distortion lives in normalised coordinates) to keep the run short.

    .venv/bin/python benchmarks/bench_holes.py                 # all rows, about a minute
    .venv/bin/python benchmarks/bench_holes.py --quick         # fewer frames, about 15 s
    .venv/bin/python benchmarks/bench_holes.py --rows oblique  # only the oblique rows
"""

from __future__ import annotations

import os

# one core: the thread limits must be set before numpy loads
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import math
import statistics
import time
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from monoguide.drivers.sim.hole_renderer import (
    Glare,
    HoleSpec,
    PartEdge,
    RenderSettings,
    blur_sigma_at,
    defocus_for_depth_of_field,
    render_expected_image,
    render_view,
    scatter_clutter,
)
from monoguide.solver import frames
from monoguide.solver.camera import PAPER_CAMERA, CameraModel
from monoguide.solver.ellipse import fit_ellipse
from monoguide.solver.errors import FeatureNotFound
from monoguide.solver.holes import find_holes, measure_hole, perspective_correction

CONTRASTS = {"strong": (190.0, 25.0), "medium": (160.0, 60.0), "weak": (125.0, 80.0)}
DISTANCE_MM = 650.0
WRONG_PICK_PX = 1.0
NOMINAL_OFFSET_PX = 15.0
OBLIQUE_TILTS_DEG = (30.0, 40.0)
DEPTH_RANGE_MM = (550.0, 800.0)
ENVELOPE_MM = 50.0
ENVELOPE_DEG = 5.0
CROP_PX = 640


@dataclass
class Tally:
    """Per-hole results of one group of conditions."""

    raw: list[float] = field(default_factory=list)  # |centre error| px, uncorrected
    corrected: list[float] = field(default_factory=list)
    crb: list[float] = field(default_factory=list)  # sqrt(trace CRB) px
    baseline: list[float] = field(default_factory=list)
    holes: int = 0
    found: int = 0
    wrong: int = 0
    baseline_found: int = 0
    full_frame_found: int = 0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--frames", type=int, default=120)
    parser.add_argument("--oblique-frames", type=int, default=60, help="frames per oblique tilt")
    parser.add_argument("--quick", action="store_true", help="16 frames, 12 per oblique tilt")
    parser.add_argument("--rows", choices=("all", "planar", "oblique"), default="all")
    parser.add_argument("--seed", type=int, default=3)
    args = parser.parse_args()
    n_frames = 16 if args.quick else args.frames
    cv2.setNumThreads(1)
    if args.rows in ("all", "planar"):
        _run_planar(n_frames, args.seed)
    if args.rows in ("all", "oblique"):
        _run_oblique(12 if args.quick else args.oblique_frames, args.seed)


def _run_planar(n_frames: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    groups: dict[str, Tally] = {}
    t_roi: list[float] = []
    t_full: list[float] = []
    t_base: list[float] = []
    for i in range(n_frames):
        contrast = list(CONTRASTS)[i % len(CONTRASTS)]
        scene = _draw_scene(rng, contrast)
        view = render_view(PAPER_CAMERA, scene.T_c_w, scene.holes, scene.settings, rng, scene.clutter)
        start = time.perf_counter()
        full = find_holes(view.image)
        t_full.append(time.perf_counter() - start)
        elapsed_roi = 0.0
        elapsed_base = 0.0
        for k, hole in enumerate(scene.holes):
            tally_keys = ["all", f"contrast {contrast}", _radius_group(hole.radius_mm), _blur_group(scene.settings)]
            tallies = [groups.setdefault(key, Tally()) for key in tally_keys]
            truth = view.centers_px[k]
            r_px = _true_radius_px(scene.T_c_w, hole)
            expected = truth + rng.normal(0.0, NOMINAL_OFFSET_PX / math.sqrt(2.0), 2)
            r_expected = r_px * rng.uniform(0.95, 1.05)
            half = 3.0 * r_expected + 40.0
            roi = (int(expected[0] - half), int(expected[1] - half), int(2 * half), int(2 * half))
            start = time.perf_counter()
            try:
                hit = measure_hole(view.image, expected, r_expected, roi=roi, max_offset_px=3.0 * r_expected)
                center = hit.center
            except FeatureNotFound:
                center = None
            elapsed_roi += time.perf_counter() - start
            start = time.perf_counter()
            base = _baseline(view.image, roi, expected, r_expected)
            elapsed_base += time.perf_counter() - start
            correction = perspective_correction(PAPER_CAMERA, scene.T_c_w_approx, hole.center_w,
                                                np.asarray(hole.normal_w), hole.radius_mm)
            crb = _crb_center(PAPER_CAMERA, scene.T_c_w, hole, scene.settings, truth)
            in_full = any(np.hypot(*(h.center - truth)) < WRONG_PICK_PX for h in full)
            for tally in tallies:
                _tally_hole(tally, center, correction, truth, base, crb, in_full)
        t_roi.append(elapsed_roi)
        t_base.append(elapsed_base)
    _print_accuracy(groups, f"{n_frames} frames 2456 x 2058")
    _print_times(t_roi, t_full, t_base)


def _run_oblique(n_frames: int, seed: int) -> None:
    """The oblique rows: ``n_frames`` per tilt of :data:`OBLIQUE_TILTS_DEG`, one hole each."""
    rng = np.random.default_rng(seed + 1000)
    groups: dict[str, Tally] = {}
    depths: list[float] = []
    angles: list[float] = []
    for tilt in OBLIQUE_TILTS_DEG:
        for i in range(n_frames):
            contrast = list(CONTRASTS)[i % len(CONTRASTS)]
            scene, camera, depth, angle = _draw_oblique_scene(rng, contrast, tilt)
            depths.append(depth)
            angles.append(angle)
            view = render_view(camera, scene.T_c_w, scene.holes, scene.settings, rng, scene.clutter)
            full = find_holes(view.image)
            hole, truth = scene.holes[0], view.centers_px[0]
            depth_group = "550-650 mm" if depth < 650.0 else "650-800 mm"
            keys = [f"oblique {tilt:.0f} deg", f"obl {tilt:.0f} {contrast}", f"oblique depth {depth_group}"]
            tallies = [groups.setdefault(key, Tally()) for key in keys]
            r_px = _imaged_radius_px(camera, scene.T_c_w, hole)
            expected = truth + rng.normal(0.0, NOMINAL_OFFSET_PX / math.sqrt(2.0), 2)
            r_expected = r_px * rng.uniform(0.95, 1.05)
            try:
                center = measure_hole(view.image, expected, r_expected, max_offset_px=3.0 * r_expected).center
            except FeatureNotFound:
                center = None
            half = 3.0 * r_expected + 40.0
            roi = (int(expected[0] - half), int(expected[1] - half), int(2 * half), int(2 * half))
            base = _baseline(view.image, roi, expected, r_expected)
            correction = perspective_correction(camera, scene.T_c_w_approx, hole.center_w,
                                                np.asarray(hole.normal_w), hole.radius_mm)
            crb = _crb_center(camera, scene.T_c_w, hole, scene.settings, truth)
            in_full = any(np.hypot(*(h.center - truth)) < WRONG_PICK_PX for h in full)
            for tally in tallies:
                _tally_hole(tally, center, correction, truth, base, crb, in_full)
    _print_accuracy(groups, f"oblique: {n_frames} frames per tilt, {CROP_PX} x {CROP_PX} crops, one hole each")
    print(f"depth {min(depths):.0f} .. {max(depths):.0f} mm, line of sight {min(angles):.1f} .. {max(angles):.1f} "
          f"deg from the sheet normal")


def _tally_hole(tally: Tally, center: np.ndarray | None, correction: np.ndarray, truth: np.ndarray,
                base: np.ndarray | None, crb: float, in_full: bool) -> None:
    tally.holes += 1
    tally.crb.append(crb)
    tally.full_frame_found += in_full
    if center is not None:
        err = float(np.hypot(*(center - truth)))
        if err > WRONG_PICK_PX:
            tally.wrong += 1
        else:
            tally.found += 1
            tally.raw.append(err)
            tally.corrected.append(float(np.hypot(*(center - correction - truth))))
    if base is not None and np.hypot(*(base - truth)) < WRONG_PICK_PX:
        tally.baseline_found += 1
        tally.baseline.append(float(np.hypot(*(base - truth))))


@dataclass
class Scene:
    T_c_w: np.ndarray
    T_c_w_approx: np.ndarray
    holes: list[HoleSpec]
    clutter: list[HoleSpec]
    settings: RenderSettings


def _draw_scene(rng: np.random.Generator, contrast: str) -> Scene:
    """Camera 650 mm above the sheet z=0 of the part, tilted up to 6 deg; two holes anywhere in view."""
    tilt = rng.uniform(0.0, math.radians(6.0))
    axis = rng.uniform(0.0, 2.0 * math.pi)
    R = frames.rotvec_to_matrix(np.array([math.pi, 0.0, 0.0])) @ frames.rotvec_to_matrix(
        np.array([tilt * math.cos(axis), tilt * math.sin(axis), rng.uniform(-math.pi, math.pi)]))
    T_c_w = frames.make_T(R.T, np.array([0.0, 0.0, DISTANCE_MM]))
    T_c_w_approx = frames.make_T(
        frames.rotvec_to_matrix(rng.normal(0.0, math.radians(0.2) / math.sqrt(3.0), 3)) @ T_c_w[:3, :3],
        T_c_w[:3, 3] + rng.normal(0.0, 1.0 / math.sqrt(3.0), 3))
    holes: list[HoleSpec] = []
    clutter: list[HoleSpec] = []
    while len(holes) < 2:
        radius = rng.uniform(4.0, 10.0)
        pixel = np.array([rng.uniform(200, PAPER_CAMERA.width - 200), rng.uniform(200, PAPER_CAMERA.height - 200)])
        center = _pixel_on_sheet(T_c_w, pixel)
        hole = HoleSpec(center_w=center, radius_mm=radius)
        if any(np.linalg.norm(center - h.center_w) < 80.0 for h in holes):
            continue
        holes.append(hole)
        clutter += scatter_clutter(hole, rng, count=3)
    sheet, hole_grey = CONTRASTS[contrast]
    settings = RenderSettings(
        blur_sigma_px=rng.uniform(0.7, 1.5), noise_sigma=rng.uniform(1.5, 4.0), sheet_grey=sheet,
        hole_grey=hole_grey, light_gradient=rng.uniform(0.0, 0.25), light_direction_deg=rng.uniform(0, 360))
    if rng.random() < 0.5:
        settings = replace(settings, glare=_glare_away_from(rng, T_c_w, holes))
    if rng.random() < 0.5:
        settings = replace(settings, part_edge=_edge_away_from(rng, holes + clutter))
    return Scene(T_c_w, T_c_w_approx, holes, clutter, settings)


def _draw_oblique_scene(rng: np.random.Generator, contrast: str,
                        tilt_deg: float) -> tuple[Scene, CameraModel, float, float]:
    """One hole on the sheet z = 0 seen along a line of sight ``tilt_deg`` from its normal, then the part
    deviated within the envelope; returns the scene (in a crop camera), the crop camera, the hole's depth
    (mm) and its actual viewing angle (deg)."""
    f_px = math.sqrt(PAPER_CAMERA.fx * PAPER_CAMERA.fy)
    focus_mm, aperture_mm = defocus_for_depth_of_field(f_px, *DEPTH_RANGE_MM, circle_px=2.0)
    while True:
        radius = rng.uniform(4.0, 10.0)
        hole = HoleSpec(center_w=np.zeros(3), radius_mm=radius)
        azimuth = rng.uniform(0.0, 2.0 * math.pi)
        tilt = math.radians(tilt_deg)
        sight = np.array([math.sin(tilt) * math.cos(azimuth), math.sin(tilt) * math.sin(azimuth), math.cos(tilt)])
        T_c_w_nominal = _look_at(rng.uniform(575.0, 775.0) * sight, rng.normal(0.0, 20.0, 3) * (1, 1, 0),
                                 rng.uniform(0.0, 2.0 * math.pi))
        centre = np.array([rng.uniform(-800.0, 800.0), rng.uniform(-500.0, 500.0), 0.0])
        rotation = frames.rotvec_to_matrix(np.radians(rng.uniform(-ENVELOPE_DEG, ENVELOPE_DEG, 3)))
        deviation = frames.make_T(rotation, centre - rotation @ centre + rng.uniform(-ENVELOPE_MM, ENVELOPE_MM, 3))
        T_c_w = T_c_w_nominal @ deviation
        center_c = T_c_w[:3, :3] @ hole.center_w + T_c_w[:3, 3]
        truth = PAPER_CAMERA.project(center_c[None])[0]
        depth = float(center_c[2])
        margin = 100.0
        if not (DEPTH_RANGE_MM[0] <= depth <= DEPTH_RANGE_MM[1] and margin <= truth[0] <= PAPER_CAMERA.width - margin
                and margin <= truth[1] <= PAPER_CAMERA.height - margin):
            continue
        normal_c = T_c_w[:3, :3] @ np.asarray(hole.normal_w, dtype=float)
        angle = math.degrees(math.acos(abs(float(normal_c @ center_c)) / np.linalg.norm(center_c)))
        break
    x0 = int(truth[0]) - CROP_PX // 2 + int(rng.integers(-150, 151))
    y0 = int(truth[1]) - CROP_PX // 2 + int(rng.integers(-150, 151))
    camera = replace(PAPER_CAMERA, width=CROP_PX, height=CROP_PX, cx=PAPER_CAMERA.cx - x0, cy=PAPER_CAMERA.cy - y0)
    T_c_w_approx = frames.make_T(
        frames.rotvec_to_matrix(rng.normal(0.0, math.radians(0.2) / math.sqrt(3.0), 3)) @ T_c_w[:3, :3],
        T_c_w[:3, 3] + rng.normal(0.0, 1.0 / math.sqrt(3.0), 3))
    clutter = scatter_clutter(hole, rng, count=3)
    sheet, hole_grey = CONTRASTS[contrast]
    settings = RenderSettings(
        blur_sigma_px=rng.uniform(0.7, 1.5), noise_sigma=rng.uniform(1.5, 4.0), sheet_grey=sheet,
        hole_grey=hole_grey, light_gradient=rng.uniform(0.0, 0.25), light_direction_deg=rng.uniform(0, 360),
        focus_distance_mm=focus_mm, aperture_mm=aperture_mm)
    if rng.random() < 0.5:
        settings = replace(settings, glare=_glare_away_from(rng, T_c_w, [hole], camera))
    if rng.random() < 0.5:
        settings = replace(settings, part_edge=_edge_away_from(rng, [hole, *clutter]))
    return Scene(T_c_w, T_c_w_approx, [hole], clutter, settings), camera, depth, angle


def _look_at(eye: np.ndarray, target: np.ndarray, roll: float) -> np.ndarray:
    """``T_c_w`` of a camera at ``eye`` (3,) looking at ``target`` (3,), turned by ``roll`` rad about its axis."""
    z = target - eye
    z /= np.linalg.norm(z)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R_w_c = np.column_stack([x, y, z]) @ frames.rotvec_to_matrix(np.array([0.0, 0.0, roll]))
    return frames.make_T(R_w_c.T, -R_w_c.T @ eye)


def _imaged_radius_px(camera: CameraModel, T_c_w: np.ndarray, hole: HoleSpec) -> float:
    """sqrt(a b) of the rim's image: foreshortened by the viewing angle."""
    normal = np.asarray(hole.normal_w, dtype=float)
    e1 = np.cross(normal, [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(normal, e1)
    t = np.linspace(0.0, 2.0 * math.pi, 180, endpoint=False)
    rim = hole.center_w + hole.radius_mm * (np.cos(t)[:, None] * e1 + np.sin(t)[:, None] * e2)
    return fit_ellipse(camera.project(rim @ T_c_w[:3, :3].T + T_c_w[:3, 3])).mean_radius


def _pixel_on_sheet(T_c_w: np.ndarray, pixel: np.ndarray) -> np.ndarray:
    ray_c = PAPER_CAMERA.pixels_to_rays(pixel[None, :])[0]
    T_w_c = frames.invert(T_c_w)
    origin, direction = T_w_c[:3, 3], T_w_c[:3, :3] @ ray_c
    return origin - origin[2] / direction[2] * direction


def _glare_away_from(rng: np.random.Generator, T_c_w: np.ndarray, holes: list[HoleSpec],
                     camera: CameraModel = PAPER_CAMERA) -> Glare:
    sigma = rng.uniform(30.0, 80.0)
    centers = [camera.project((T_c_w[:3, :3] @ h.center_w + T_c_w[:3, 3])[None])[0] for h in holes]
    while True:
        c = np.array([rng.uniform(0, camera.width), rng.uniform(0, camera.height)])
        if all(np.hypot(*(c - p)) > 3.0 * sigma + 60.0 for p in centers):
            return Glare(center_px=(float(c[0]), float(c[1])), sigma_px=sigma, peak_grey=rng.uniform(40.0, 100.0))


def _edge_away_from(rng: np.random.Generator, holes: list[HoleSpec]) -> PartEdge:
    while True:
        ang = rng.uniform(0.0, 2.0 * math.pi)
        outward = np.array([math.cos(ang), math.sin(ang), 0.0])
        point = outward * rng.uniform(100.0, 250.0)
        if all((point - h.center_w) @ outward > h.radius_mm + 10.0 for h in holes):
            return PartEdge(point_w=point, outward_w=outward)


def _true_radius_px(T_c_w: np.ndarray, hole: HoleSpec) -> float:
    depth = float((T_c_w[:3, :3] @ hole.center_w + T_c_w[:3, 3])[2])
    return hole.radius_mm * math.sqrt(PAPER_CAMERA.fx * PAPER_CAMERA.fy) / depth


def _radius_group(radius_mm: float) -> str:
    return "radius 4-6 mm" if radius_mm < 6 else ("radius 6-8 mm" if radius_mm < 8 else "radius 8-10 mm")


def _blur_group(settings: RenderSettings) -> str:
    return "blur 0.7-1.1 px" if settings.blur_sigma_px < 1.1 else "blur 1.1-1.5 px"


def _baseline(image: np.ndarray, roi: tuple[int, int, int, int], expected: np.ndarray,
              r_expected: float) -> np.ndarray | None:
    """What a user writes first: Otsu, outer contours, cv2.fitEllipse, the nearest of the right size."""
    x, y, w, h = roi
    x0, y0 = max(x, 0), max(y, 0)
    crop = image[y0:min(y + h, image.shape[0]), x0:min(x + w, image.shape[1])]
    _, dark = cv2.threshold(crop, 0, 255, cv2.THRESH_BINARY_INV | cv2.THRESH_OTSU)
    contours, _ = cv2.findContours(dark, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    best, best_d = None, math.inf
    for contour in contours:
        if len(contour) < 5:
            continue
        (cu, cv_), (da, db), _ = cv2.fitEllipse(contour)
        if abs(math.sqrt(da * db) / 2.0 / r_expected - 1.0) > 0.25:
            continue
        center = np.array([cu + x0, cv_ + y0])
        d = float(np.hypot(*(center - expected)))
        if d < best_d:
            best, best_d = center, d
    return best


def _crb_center(camera: CameraModel, T_c_w: np.ndarray, hole: HoleSpec, settings: RenderSettings,
                truth: np.ndarray) -> float:
    """sqrt(trace) of the CRB of the centre: sigma^2 (J^T J)^-1, J = d(noise-free image)/d(u, v).

    Rendered in a crop around the hole by a camera with the principal point moved (distortion lives
    in normalised coordinates, so the crop is exact); the light field is frozen at its local value.
    """
    depth = float((T_c_w[:3, :3] @ hole.center_w + T_c_w[:3, 3])[2])
    sigma = float(blur_sigma_at(depth, settings, math.sqrt(camera.fx * camera.fy)))
    half = int(_true_radius_px(T_c_w, hole) + 6.0 * sigma + 8)
    x0, y0 = int(truth[0]) - half, int(truth[1]) - half
    crop_cam = replace(camera, width=2 * half, height=2 * half, cx=camera.cx - x0, cy=camera.cy - y0)
    a = math.cos(math.radians(settings.light_direction_deg))
    b = math.sin(math.radians(settings.light_direction_deg))
    un, vn = 2.0 * truth[0] / (camera.width - 1) - 1.0, 2.0 * truth[1] / (camera.height - 1) - 1.0
    light = 1.0 + settings.light_gradient * (a * un + b * vn) / (abs(a) + abs(b))
    local = replace(settings, light_gradient=0.0, sheet_grey=settings.sheet_grey * light,
                    hole_grey=settings.hole_grey * light, glare=None, part_edge=None)
    normal = np.asarray(hole.normal_w, dtype=float)
    e1 = np.cross(normal, [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(normal, e1)
    delta = 0.01  # mm
    jac_img, jac_uv = [], []
    for e in (e1, e2):
        images, centers = [], []
        for s in (-1.0, 1.0):
            moved = replace(hole, center_w=hole.center_w + s * delta * e)
            images.append(render_expected_image(crop_cam, T_c_w, [moved], local).astype(float))
            centers.append(crop_cam.project((T_c_w[:3, :3] @ moved.center_w + T_c_w[:3, 3])[None])[0])
        jac_img.append(((images[1] - images[0]) / (2 * delta)).ravel())
        jac_uv.append((centers[1] - centers[0]) / (2 * delta))
    J = np.stack(jac_img, axis=1) @ np.linalg.inv(np.stack(jac_uv, axis=1))  # d image / d(u, v)
    variance = settings.noise_sigma**2 + 1.0 / 12.0  # sensor noise plus 8-bit quantisation
    return float(math.sqrt(np.trace(variance * np.linalg.inv(J.T @ J))))


def _rms(values: list[float]) -> float:
    return math.sqrt(sum(v * v for v in values) / len(values)) if values else math.nan


def _print_accuracy(groups: dict[str, Tally], what: str) -> None:
    print(f"\nHole centres, {what}, errors |e| px against the projected 3-D centre")
    header = (f"{'condition':<26}{'holes':>6}{'found':>7}{'wrong':>6}{'med raw':>9}{'RMS raw':>9}{'max raw':>9}"
              f"{'RMS corr':>9}{'max corr':>9}{'CRB':>7}{'ours/CRB':>9}  |{'Otsu+fitEllipse: found':>23}"
              f"{'RMS':>7}{'max':>7}")
    print(header)
    print("-" * len(header))
    for name, t in sorted(groups.items(), key=lambda kv: (kv[0] != "all", not kv[0].startswith("oblique "),
                                                           kv[0])):
        crb = _rms(t.crb)
        print(f"{name:<26}{t.holes:>6}{t.found:>7}{t.wrong:>6}{statistics.median(t.raw or [math.nan]):>9.4f}"
              f"{_rms(t.raw):>9.4f}{max(t.raw, default=math.nan):>9.4f}{_rms(t.corrected):>9.4f}"
              f"{max(t.corrected, default=math.nan):>9.4f}{crb:>7.4f}{_rms(t.corrected) / crb:>9.2f}  |"
              f"{t.baseline_found:>20}/{t.holes:<2}{_rms(t.baseline):>7.3f}{max(t.baseline, default=math.nan):>7.3f}")
    totals = [t for name, t in groups.items() if name == "all" or name.endswith(" deg")]  # each hole once
    found, holes = sum(t.full_frame_found for t in totals), sum(t.holes for t in totals)
    print(f"recall of find_holes on the whole image (no ROI, no expectation): {found}/{holes}")


def _print_times(t_roi: list[float], t_full: list[float], t_base: list[float]) -> None:
    print("\nTime per 2456 x 2058 frame, one core (two holes per frame), ms")
    print(f"{'':<42}{'median':>8}{'max':>8}")
    for name, values in (("measure_hole x2 with ROI", t_roi), ("find_holes, full frame, no ROI", t_full),
                         ("baseline Otsu+fitEllipse x2 with ROI", t_base)):
        print(f"{name:<42}{1e3 * statistics.median(values):>8.1f}{1e3 * max(values):>8.1f}")


if __name__ == "__main__":
    main()
