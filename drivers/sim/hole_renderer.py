"""A photometric renderer of featured holes with exact ground truth (issue 3).

What the flange camera sees at a measuring pose: sheet metal with circular holes, each projected
exactly in perspective through the lens distortion of :class:`CameraModel` (Eq. 7-8), then blur (the
lens's own, plus defocus that grows with the distance from the focus plane: a thin lens), uneven
lighting, an optional glare spot and part edge, sensor noise and 8-bit quantisation.

Exactness: a pixel's hole coverage is the fraction of its area whose back-projected ray meets the
sheet plane inside the circle. Pixels far from the rim are decided by their centre; pixels in a band
around the rim are supersampled (``RenderSettings.supersample``\\ :sup:`2` sub-pixels, each with a
linear ramp across its own width), so the rendered rim sits where the model says to ~1e-3 px.
Only the pixels within a few px of the projected rim are back-projected (the others lie clearly inside or
outside the rim's projected polygon), which keeps a full 2456 x 2058 frame at ~0.2 s without defocus.

Any dark disc in its own plane renders this way: the simulated camera draws the cell's fixed reference marks
(on the fixture, in planes other than the sheet's) as ``clutter`` of :func:`render_view`, with the holes.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from monoguide.solver.camera import CameraModel

_RIM_POLYGON_POINTS = 256
_BBOX_MARGIN_PX = 3
_RIM_NEAR_PX = 2  # pixels this close to the projected rim polygon are decided by back-projection, the others by it
_POLY_SHIFT = 8  # the rim polygon is rasterised with 1/256 px precision
_EDGE_GRID_STEP_PX = 8
_DEPTH_GRID_STEP_PX = 16
_MAX_DEFOCUS_CIRCLE_PX = 40.0
_BLUR_LEVEL_STEP_PX = 0.1  # defocus: the frame is blurred at sigmas this far apart and blended
_MAX_BLUR_LEVELS = 16


@dataclass(frozen=True, eq=False)
class HoleSpec:
    """One circular hole in the part: centre ``center_w`` (3,) mm and sheet normal ``normal_w`` (3,) in the
    part frame, radius in mm."""

    center_w: np.ndarray
    radius_mm: float
    normal_w: np.ndarray | Sequence[float] = (0.0, 0.0, 1.0)


@dataclass(frozen=True)
class Glare:
    """A bright specular spot on the sheet (not inside holes): Gaussian of ``sigma_px`` at ``center_px``
    adding ``peak_grey`` grey levels before exposure."""

    center_px: tuple[float, float]
    sigma_px: float = 40.0
    peak_grey: float = 60.0


@dataclass(frozen=True, eq=False)
class PartEdge:
    """A straight edge of the part: the sheet plane through ``point_w`` with normal ``normal_w`` ends along
    the line through ``point_w``; beyond it, in the in-plane direction ``outward_w`` (3,), the camera
    sees the floor at ``beyond_grey``."""

    point_w: np.ndarray | Sequence[float]
    outward_w: np.ndarray | Sequence[float]
    normal_w: np.ndarray | Sequence[float] = (0.0, 0.0, 1.0)
    beyond_grey: float = 70.0


@dataclass(frozen=True)
class RenderSettings:
    """Photometry of one image; the defaults are a good, ordinary line image.

    Grey values are before lighting and exposure. ``light_gradient`` is the +- fraction of brightness
    across the frame along ``light_direction_deg`` (0 = +x, 90 = +y). ``exposure`` multiplies the
    brightness before quantisation, which saturates at 255. ``supersample`` is the number of
    sub-pixels per pixel side in the band around each rim.

    Blur: ``blur_sigma_px`` is the Gaussian sigma of a point in the focus plane (lens and pixel). With
    ``aperture_mm`` > 0 (the entrance pupil's diameter: focal length / f-number) and
    ``focus_distance_mm`` (the depth, camera z, in focus) a point at depth ``d`` is also spread over the
    thin lens's blur circle of diameter ``aperture_mm * f_px * |1/d - 1/focus_distance_mm|`` px, whose
    sigma (a quarter of the diameter) adds in quadrature (:func:`blur_sigma_at`). The depth of each pixel
    is that of the sheet plane of the nearest hole. ``aperture_mm`` 0 keeps one blur for the frame.
    """

    blur_sigma_px: float = 1.0
    focus_distance_mm: float | None = None
    aperture_mm: float = 0.0
    noise_sigma: float = 2.0
    sheet_grey: float = 180.0
    hole_grey: float = 30.0
    light_gradient: float = 0.15
    light_direction_deg: float = 30.0
    exposure: float = 1.0
    glare: Glare | None = None
    part_edge: PartEdge | None = None
    supersample: int = 4


@dataclass
class RenderedView:
    """A rendered image and its ground truth.

    ``image`` (height, width) uint8; ``centers_px`` (n, 2) the exact projection of each hole's 3-D centre
    (raw pixels); ``in_view`` (n,) bool, True when the hole's whole rim lies inside the image.
    """

    image: np.ndarray
    centers_px: np.ndarray
    in_view: np.ndarray


def blur_sigma_at(depth_mm: float | np.ndarray, settings: RenderSettings, f_px: float) -> float | np.ndarray:
    """Gaussian blur sigma (px) of a point at camera depth ``depth_mm`` (scalar or array): the in-focus
    ``settings.blur_sigma_px`` and the thin-lens defocus of a camera of focal length ``f_px`` px."""
    circle = defocus_circle_px(depth_mm, settings, f_px)
    return np.sqrt(settings.blur_sigma_px**2 + (circle / 4.0) ** 2)


def defocus_circle_px(depth_mm: float | np.ndarray, settings: RenderSettings, f_px: float) -> float | np.ndarray:
    """Diameter (px) of the thin lens's blur circle for a point at camera depth ``depth_mm``:
    ``aperture_mm * f_px * |1/depth - 1/focus_distance_mm|``; 0 without an aperture or a focus distance."""
    if settings.aperture_mm <= 0.0 or settings.focus_distance_mm is None:
        return np.zeros_like(depth_mm, dtype=float) if isinstance(depth_mm, np.ndarray) else 0.0
    with np.errstate(divide="ignore"):
        inv = 1.0 / np.asarray(depth_mm, dtype=float)
    circle = settings.aperture_mm * f_px * np.abs(inv - 1.0 / settings.focus_distance_mm)
    return np.minimum(circle, _MAX_DEFOCUS_CIRCLE_PX) if isinstance(depth_mm, np.ndarray) else float(
        min(circle, _MAX_DEFOCUS_CIRCLE_PX))


def defocus_for_depth_of_field(f_px: float, near_mm: float, far_mm: float,
                               circle_px: float = 2.0) -> tuple[float, float]:
    """(focus_distance_mm, aperture_mm) whose blur circle is ``circle_px`` px at both ``near_mm`` and
    ``far_mm`` and smaller between: the focus distance is their harmonic mean."""
    if not 0.0 < near_mm < far_mm:
        raise ValueError(f"depth of field {near_mm} .. {far_mm} mm: need 0 < near < far")
    if not circle_px > 0.0:
        raise ValueError(f"circle of confusion {circle_px} px must be positive")
    half = 0.5 * (1.0 / near_mm - 1.0 / far_mm)
    return 1.0 / (0.5 * (1.0 / near_mm + 1.0 / far_mm)), circle_px / (f_px * half)


def render_view(
    camera: CameraModel,
    T_c_w: np.ndarray,
    holes: Sequence[HoleSpec],
    settings: RenderSettings = RenderSettings(),
    rng: np.random.Generator | None = None,
    clutter: Sequence[HoleSpec] = (),
) -> RenderedView:
    """Render the camera image of ``holes`` (with ground truth) and ``clutter`` (other holes, no truth).

    ``T_c_w`` (4, 4) mm maps part-frame points into the camera frame. ``rng`` draws the sensor noise
    (a fresh unseeded generator when None; pass a seeded one for reproducible images).
    """
    rng = rng if rng is not None else np.random.default_rng()
    radiance = _radiance(camera, T_c_w, [*holes, *clutter], settings)
    if settings.noise_sigma > 0:  # noise before the clip: a saturated pixel reads 255 whatever the noise
        radiance += rng.standard_normal(radiance.shape, dtype=np.float32) * np.float32(settings.noise_sigma)
    # saturate_cast rounds to nearest and clips at 255; negative values must be clipped first
    image = cv2.convertScaleAbs(cv2.max(radiance, 0.0))
    centers = np.array([_hole_center_px(camera, T_c_w, h) for h in holes]).reshape(-1, 2)
    in_view = np.array([bool(np.all(camera.in_image(_rim_polygon_px(camera, T_c_w, h)))) for h in holes],
                       dtype=bool)
    return RenderedView(image=image, centers_px=centers, in_view=in_view)


def render_expected_image(
    camera: CameraModel,
    T_c_w: np.ndarray,
    holes: Sequence[HoleSpec],
    settings: RenderSettings = RenderSettings(),
) -> np.ndarray:
    """The noise-free, unquantised image (height, width) float32: exposure applied and clipped at 255.

    This is the mean of :func:`render_view`'s image where nothing saturates; the Cramér-Rao bound is
    computed from its derivative.
    """
    return np.minimum(_radiance(camera, T_c_w, holes, settings), np.float32(255.0))


def hole_coverage(
    camera: CameraModel, T_c_w: np.ndarray, hole: HoleSpec, supersample: int = 4
) -> tuple[tuple[int, int, int, int] | None, np.ndarray]:
    """Fraction of each pixel inside ``hole``, in the pixel box ``(x0, y0, x1, y1)`` (exclusive ends).

    Returns ``(None, empty)`` when the hole lies wholly outside the image. Coverage (y1-y0, x1-x0) float32.
    """
    rim = _rim_polygon_px(camera, T_c_w, hole)
    x0 = max(math.floor(rim[:, 0].min()) - _BBOX_MARGIN_PX, 0)
    y0 = max(math.floor(rim[:, 1].min()) - _BBOX_MARGIN_PX, 0)
    x1 = min(math.ceil(rim[:, 0].max()) + _BBOX_MARGIN_PX + 1, camera.width)
    y1 = min(math.ceil(rim[:, 1].max()) + _BBOX_MARGIN_PX + 1, camera.height)
    if x1 <= x0 or y1 <= y0:
        return None, np.zeros((0, 0), np.float32)
    plane = _HolePlane(T_c_w, hole)
    us, vs = np.meshgrid(np.arange(x0, x1, dtype=float), np.arange(y0, y1, dtype=float))
    pix = np.stack([us.ravel(), vs.ravel()], axis=1)
    # only the pixels near the rim are back-projected (and their neighbours, for the gradient); the others lie far
    # inside or outside the projected rim polygon, which decides them
    inside, near = _rim_masks(rim - np.array([x0, y0]), us.shape)
    rho = np.full(us.shape, np.nan)
    wanted = cv2.dilate(near.view(np.uint8), np.ones((3, 3), np.uint8)).view(bool)
    rho[wanted] = plane.radius_at(camera, pix[wanted.ravel()])
    gy, gx = np.gradient(rho)
    mm_per_px = np.maximum(np.hypot(gx[near], gy[near]), 1e-12)  # |grad rho|: plane mm per image px, locally
    dist_near = (rho[near] - hole.radius_mm) / mm_per_px
    coverage = inside.astype(np.float32)
    coverage[near] = dist_near < 0
    in_band = np.abs(dist_near) < 1.0  # a rim within sqrt(2)/2 px of the centre can touch the pixel
    band = np.zeros(us.shape, bool)
    band[near] = in_band
    mm_per_px_band = mm_per_px[in_band]
    if np.any(band):
        s = int(supersample)
        offs = (np.arange(s) + 0.5) / s - 0.5
        ou, ov = np.meshgrid(offs, offs)
        sub = pix[band.ravel()][:, None, :] + np.stack([ou.ravel(), ov.ravel()], axis=1)[None, :, :]
        rho_sub = plane.radius_at(camera, sub.reshape(-1, 2)).reshape(-1, s * s)
        d_sub = (rho_sub - hole.radius_mm) / mm_per_px_band[:, None] * s  # in sub-pixel widths
        coverage[band] = np.clip(0.5 - d_sub, 0.0, 1.0).mean(axis=1)
    return (x0, y0, x1, y1), coverage


def _rim_masks(rim_px: np.ndarray, shape: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    """(inside, near) bool masks of ``shape``: pixel centres inside the rim polygon ``rim_px`` (m, 2) (pixel
    coordinates of the box), and those within about :data:`_RIM_NEAR_PX` px of it (the ones decided exactly)."""
    if not float(np.abs(rim_px).max()) < 2.0 ** (30 - _POLY_SHIFT):  # beyond the rasteriser's reach: all exactly
        return np.zeros(shape, bool), np.ones(shape, bool)
    poly = [np.round(rim_px * (1 << _POLY_SHIFT)).astype(np.int32).reshape(-1, 1, 2)]
    inside = np.zeros(shape, np.uint8)
    cv2.fillPoly(inside, poly, 1, lineType=cv2.LINE_8, shift=_POLY_SHIFT)
    near = np.zeros(shape, np.uint8)
    cv2.polylines(near, poly, True, 1, thickness=2 * _RIM_NEAR_PX + 1, lineType=cv2.LINE_8, shift=_POLY_SHIFT)
    return inside.view(bool), near.view(bool)


def scatter_clutter(
    hole: HoleSpec,
    rng: np.random.Generator,
    count: int = 3,
    radius_factors: Sequence[float] = (0.55, 0.7, 1.45, 1.8),
    gap_mm: tuple[float, float] = (4.0, 25.0),
) -> list[HoleSpec]:
    """``count`` other holes of other sizes around ``hole`` in its sheet plane, none overlapping.

    Each radius is ``hole.radius_mm`` times one of ``radius_factors``; the rim-to-rim gap to ``hole`` is
    drawn from ``gap_mm``.
    """
    normal = _unit(np.asarray(hole.normal_w, dtype=float))
    e1, e2 = _plane_basis(normal)
    placed: list[HoleSpec] = []
    for _ in range(200 * max(count, 1)):
        if len(placed) == count:
            break
        r = hole.radius_mm * float(rng.choice(np.asarray(radius_factors)))
        dist = hole.radius_mm + r + rng.uniform(*gap_mm)
        ang = rng.uniform(0.0, 2.0 * math.pi)
        c = np.asarray(hole.center_w, float) + dist * (math.cos(ang) * e1 + math.sin(ang) * e2)
        if all(np.linalg.norm(c - np.asarray(p.center_w)) > r + p.radius_mm + gap_mm[0] for p in placed):
            placed.append(HoleSpec(center_w=c, radius_mm=r, normal_w=normal))
    return placed


# --- private helpers -----------------------------------------------------------------------------


class _HolePlane:
    """The sheet plane of one hole, in the camera frame, for back-projecting pixels onto it."""

    def __init__(self, T_c_w: np.ndarray, hole: HoleSpec) -> None:
        R, t = T_c_w[:3, :3], T_c_w[:3, 3]
        self.center_c = R @ np.asarray(hole.center_w, dtype=float) + t
        self.normal_c = R @ _unit(np.asarray(hole.normal_w, dtype=float))

    def radius_at(self, camera: CameraModel, pixels: np.ndarray) -> np.ndarray:
        """Distance (n,) mm from the hole centre where each pixel's ray (n, 2) meets the plane."""
        xy = camera.undistort_pixels(pixels)
        rays = np.concatenate([xy, np.ones((len(xy), 1))], axis=1)
        denom = rays @ self.normal_c
        with np.errstate(divide="ignore", invalid="ignore"):
            lam = float(self.normal_c @ self.center_c) / denom
        points = rays * lam[:, None]
        rho = np.linalg.norm(points - self.center_c, axis=1)
        rho[~(lam > 0)] = np.inf  # a ray that misses the plane (or meets it behind the camera) is sheet
        return rho


def _radiance(
    camera: CameraModel, T_c_w: np.ndarray, holes: Sequence[HoleSpec], settings: RenderSettings
) -> np.ndarray:
    """The noise-free grey levels (height, width) float32 before the sensor clips them."""
    h, w = camera.height, camera.width
    reflectance = np.full((h, w), settings.sheet_grey, dtype=np.float32)
    for hole in holes:
        box, coverage = hole_coverage(camera, T_c_w, hole, settings.supersample)
        if box is None:
            continue
        x0, y0, x1, y1 = box
        reflectance[y0:y1, x0:x1] += np.float32(settings.hole_grey - settings.sheet_grey) * coverage
    if settings.glare is not None:
        reflectance += _glare_image(camera, settings.glare) * (reflectance - settings.hole_grey) / max(
            settings.sheet_grey - settings.hole_grey, 1e-6)
    if settings.part_edge is not None:
        edge_cov = _edge_coverage(camera, T_c_w, settings.part_edge)
        reflectance += (np.float32(settings.part_edge.beyond_grey) - reflectance) * edge_cov
    image = reflectance * _light_field(h, w, settings)
    if defocus_circle_px(1.0, settings, 1.0) == 0.0 or not holes:
        return _gaussian(image, settings.blur_sigma_px)
    return _blur_by_depth(image, camera, T_c_w, holes, settings)


def _gaussian(image: np.ndarray, sigma: float) -> np.ndarray:
    if sigma <= 0:
        return image
    return cv2.GaussianBlur(image, (0, 0), sigma, borderType=cv2.BORDER_REPLICATE)


def _blur_by_depth(image: np.ndarray, camera: CameraModel, T_c_w: np.ndarray, holes: Sequence[HoleSpec],
                   settings: RenderSettings) -> np.ndarray:
    """``image`` blurred by the sigma of each pixel's depth: blurred at a ladder of sigmas and blended
    per pixel with weights linear in sigma^2 (which keeps the blend's variance that of the sigma)."""
    f_px = math.sqrt(camera.fx * camera.fy)
    sigma2 = blur_sigma_at(_depth_map(camera, T_c_w, holes), settings, f_px) ** 2
    lo, hi = float(np.sqrt(sigma2.min())), float(np.sqrt(sigma2.max()))
    if hi - lo < 0.02:
        return _gaussian(image, 0.5 * (lo + hi))
    n = min(max(math.ceil((hi - lo) / _BLUR_LEVEL_STEP_PX) + 1, 2), _MAX_BLUR_LEVELS)
    levels2 = np.linspace(lo, hi, n) ** 2
    out = np.zeros_like(image)
    for k, s2 in enumerate(levels2):
        # the level's hat: rising from the level below, falling to the one above, 0 beyond (whole-frame arithmetic,
        # no masks: the min of the two ramps is the one that applies, the clip makes the rest 0)
        rising = (sigma2 - levels2[k - 1]) / (s2 - levels2[k - 1]) if k > 0 else None
        falling = (levels2[k + 1] - sigma2) / (levels2[k + 1] - s2) if k < n - 1 else None
        if rising is None:
            hat = falling
        elif falling is None:
            hat = np.where(sigma2 <= s2, rising, 0.0)
        else:
            hat = np.minimum(rising, falling)
        weight = np.clip(hat, 0.0, 1.0).astype(sigma2.dtype, copy=False)
        if np.any(weight > 0):
            out += weight * _gaussian(image, math.sqrt(s2))
    return out


def _depth_map(camera: CameraModel, T_c_w: np.ndarray, holes: Sequence[HoleSpec]) -> np.ndarray:
    """Camera depth (h, w) float32 mm of the sheet seen at each pixel: the plane of the hole whose image
    is nearest, back-projected on a coarse grid and interpolated. Rays that miss it are far away."""
    step = _DEPTH_GRID_STEP_PX
    gu = np.arange(0, camera.width + step, step, dtype=float)
    gv = np.arange(0, camera.height + step, step, dtype=float)
    uu, vv = np.meshgrid(gu, gv)
    nodes = np.stack([uu.ravel(), vv.ravel()], axis=1)
    xy = camera.undistort_pixels(nodes)
    rays = np.concatenate([xy, np.ones((len(xy), 1))], axis=1)
    planes = [_HolePlane(T_c_w, hole) for hole in holes]
    centers = np.array([camera.project(p.center_c[None])[0] if p.center_c[2] > 0 else (np.inf, np.inf)
                        for p in planes])
    nearest = np.argmin(np.hypot(nodes[:, None, 0] - centers[None, :, 0], nodes[:, None, 1] - centers[None, :, 1]),
                        axis=1)
    depth = np.full(len(nodes), 1e9)
    for k, plane in enumerate(planes):
        mine = nearest == k
        denom = rays[mine] @ plane.normal_c
        with np.errstate(divide="ignore", invalid="ignore"):
            lam = float(plane.normal_c @ plane.center_c) / denom
        depth[mine] = np.where(lam > 0, lam, 1e9)  # rays have z = 1: lam is the depth
    grid = depth.reshape(uu.shape).astype(np.float32)
    full = _interp_rows(grid, camera.height, step)
    return _interp_rows(np.ascontiguousarray(full.T), camera.width, step).T


def _hole_center_px(camera: CameraModel, T_c_w: np.ndarray, hole: HoleSpec) -> np.ndarray:
    center_c = T_c_w[:3, :3] @ np.asarray(hole.center_w, dtype=float) + T_c_w[:3, 3]
    return camera.project(center_c[None, :])[0]


def _rim_polygon_px(camera: CameraModel, T_c_w: np.ndarray, hole: HoleSpec) -> np.ndarray:
    """The rim projected at ``_RIM_POLYGON_POINTS`` points, (m, 2) raw pixels."""
    normal = _unit(np.asarray(hole.normal_w, dtype=float))
    e1, e2 = _plane_basis(normal)
    t = np.linspace(0.0, 2.0 * math.pi, _RIM_POLYGON_POINTS, endpoint=False)
    rim_w = np.asarray(hole.center_w, float) + hole.radius_mm * (
        np.cos(t)[:, None] * e1 + np.sin(t)[:, None] * e2)
    rim_c = rim_w @ T_c_w[:3, :3].T + T_c_w[:3, 3]
    if np.any(rim_c[:, 2] <= 0):
        raise ValueError(f"hole at {np.round(hole.center_w, 3).tolist()} mm is (partly) behind the camera")
    return camera.project(rim_c)


def _plane_basis(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors (3,) spanning the plane orthogonal to unit ``normal``."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(normal[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = _unit(np.cross(normal, helper))
    return e1, np.cross(normal, e1)


def _unit(v: np.ndarray) -> np.ndarray:
    n = float(np.linalg.norm(v))
    if n == 0.0:
        raise ValueError("a normal or direction vector must not be zero")
    return v / n


def _light_field(h: int, w: int, settings: RenderSettings) -> np.ndarray:
    """Multiplicative lighting and exposure (h, w) float32, 1 +- ``light_gradient`` across the frame."""
    a = math.cos(math.radians(settings.light_direction_deg))
    b = math.sin(math.radians(settings.light_direction_deg))
    scale = settings.light_gradient / max(abs(a) + abs(b), 1e-12)
    un = np.linspace(-1.0, 1.0, w, dtype=np.float32) * np.float32(a * scale)
    vn = np.linspace(-1.0, 1.0, h, dtype=np.float32) * np.float32(b * scale)
    return (np.float32(1.0) + vn[:, None] + un[None, :]) * np.float32(settings.exposure)


def _glare_image(camera: CameraModel, glare: Glare) -> np.ndarray:
    """The glare spot (h, w) float32 in grey levels, zero beyond 4 sigma."""
    out = np.zeros((camera.height, camera.width), np.float32)
    cu, cv_ = glare.center_px
    reach = 4.0 * glare.sigma_px
    x0, x1 = max(int(cu - reach), 0), min(int(cu + reach) + 1, camera.width)
    y0, y1 = max(int(cv_ - reach), 0), min(int(cv_ + reach) + 1, camera.height)
    if x1 > x0 and y1 > y0:
        gu = np.exp(-0.5 * ((np.arange(x0, x1) - cu) / glare.sigma_px) ** 2)
        gv = np.exp(-0.5 * ((np.arange(y0, y1) - cv_) / glare.sigma_px) ** 2)
        out[y0:y1, x0:x1] = (glare.peak_grey * gv[:, None] * gu[None, :]).astype(np.float32)
    return out


def _edge_coverage(camera: CameraModel, T_c_w: np.ndarray, edge: PartEdge) -> np.ndarray:
    """Fraction (h, w) float32 of each pixel beyond the part edge.

    The signed distance to the edge line, in pixels, is smooth over the image: it is computed by
    back-projection on a coarse grid and interpolated, then turned into a one-pixel linear ramp.
    """
    R, t = T_c_w[:3, :3], T_c_w[:3, 3]
    p_c = R @ np.asarray(edge.point_w, float) + t
    n_c = R @ _unit(np.asarray(edge.normal_w, float))
    out_c = R @ _unit(np.asarray(edge.outward_w, float))
    out_c = _unit(out_c - (out_c @ n_c) * n_c)
    step = _EDGE_GRID_STEP_PX
    gu = np.arange(0, camera.width + step, step, dtype=float)
    gv = np.arange(0, camera.height + step, step, dtype=float)
    uu, vv = np.meshgrid(gu, gv)
    xy = camera.undistort_pixels(np.stack([uu.ravel(), vv.ravel()], axis=1))
    rays = np.concatenate([xy, np.ones((len(xy), 1))], axis=1)
    lam = float(n_c @ p_c) / (rays @ n_c)
    s_mm = ((rays * lam[:, None] - p_c) @ out_c).reshape(uu.shape)
    gy, gx = np.gradient(s_mm, step)
    s_px = (s_mm / np.maximum(np.hypot(gx, gy), 1e-12)).astype(np.float32)
    # separable linear interpolation from the grid (node k at pixel k*step) onto the pixel raster
    full = _interp_rows(s_px, camera.height, step)
    full = _interp_rows(np.ascontiguousarray(full.T), camera.width, step).T
    return np.clip(np.float32(0.5) + full, 0.0, 1.0)


def _interp_rows(grid: np.ndarray, n: int, step: int) -> np.ndarray:
    """Linear interpolation of ``grid`` (m, k), rows at 0, step, 2 step, ..., onto rows 0..n-1 -> (n, k)."""
    pos = np.arange(n, dtype=np.float32) / np.float32(step)
    idx = np.minimum(pos.astype(np.int64), grid.shape[0] - 2)
    frac = (pos - idx)[:, None]
    return grid[idx] * (np.float32(1.0) - frac) + grid[idx + 1] * frac
