"""The calibration report's two plans of the cell, drawn to scale with matplotlib (``PLAN_SIZE``, two panels
each): the calibrated measuring poses over the part, and the calibrated cell's uncertainty map over the part's
x-y shifts in the deviation envelope."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from monoguide.daemon.config import CellConfig
from monoguide.daemon.figures import REFERENCE, SERIES, draw_style, figure_legend, label_points, new_figure, outline
from monoguide.solver.camera import CameraModel
from monoguide.solver.errors import MonoguideError
from monoguide.solver.frames import invert, make_T
from monoguide.solver.planning.prediction import observed_covariance, pose_sigmas

if TYPE_CHECKING:
    from matplotlib.figure import Figure

PLAN_SIZE = (1200, 560)  # width, height px: two panels side by side
MAP_STEPS = 11  # the uncertainty map's grid over the envelope's x and y


@draw_style
def draw_measuring_poses(r: dict[str, Any], steps: dict[str, dict[str, Any]],
                         config: CellConfig | None) -> Figure:
    """The calibrated cameras SFi (dot, line of sight to the part's plane) over the part's holes and outline,
    in the reference part's frame: from above (x right, y up) and from the side (x right, z up)."""
    if "part" in steps:
        T_cf_w0 = np.asarray(steps["part"]["T_cf_w0"], dtype=float)
    elif config is not None:
        T_cf_w0 = config.reference.T_cf_w0
    else:
        T_cf_w0 = np.eye(4)
    frame = "part frame" if "part" in steps or config is not None else "cell frame"
    T_w_cf = invert(T_cf_w0)
    cams = [(str(p.get("name")), T_w_cf @ np.asarray(p["T_cf_si"], dtype=float)) for p in r.get("poses") or []]
    centres = np.array([T[:3, 3] for _, T in cams]).reshape(-1, 3)
    ends = np.array([_axis_end(T) for _, T in cams]).reshape(-1, 3)
    points = config.part.points_w if config is not None else np.zeros((0, 3))
    names = config.part.point_names if config is not None else ()
    figure = new_figure(PLAN_SIZE)
    panels = figure.subplots(1, 2)
    for ax, (a, b, view) in zip(panels, ((0, 1, "from above: x right, y up"), (0, 2, "from the side: x right, z up")),
                                strict=True):
        span = float(np.ptp(np.vstack([points, centres, ends, np.zeros((1, 3))])[:, [a, b]], axis=0).max())
        if len(points) >= 3:
            hull = outline(points[:, [a, b]])
            ax.fill(hull[:, 0], hull[:, 1], facecolor="0.93", edgecolor=REFERENCE, label="part outline (holes)")
        if len(points):
            ax.plot(points[:, a], points[:, b], "o", color="black", markersize=5, label="featured hole")
            label_points(ax, names, points[:, [a, b]], "black", span)
        for i, ((name, _), c, e) in enumerate(zip(cams, centres, ends, strict=True)):
            colour = SERIES[i % len(SERIES)]
            ax.plot([c[a], e[a]], [c[b], e[b]], "-", color=colour, linewidth=1.5)
            ax.plot(c[a], c[b], "o", color=colour, markersize=7, label=f"{name}: camera and its line of sight")
        label_points(ax, [name for name, _ in cams], centres[:, [a, b]], "0.2", span)
        ax.margins(0.08)
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel(f"x ({frame}, mm)")
        ax.set_ylabel(f"{'yz'[b - 1]} ({frame}, mm)")
        ax.set_title(view)
    figure_legend(figure, *panels, columns=3)
    figure.suptitle(f"Measuring poses over the part ({frame}, mm, to scale)")
    return figure


def draw_uncertainty_map(r: dict[str, Any], steps: dict[str, dict[str, Any]], config: CellConfig | None
                         ) -> Figure | None:
    """The calibrated cell's uncertainty map: the predicted sigma over the part's x-y shifts (two colour maps);
    None without the config or when the layout is degenerate."""
    grid = uncertainty_grid(r, steps, config) if config is not None else None
    return None if grid is None else _uncertainty_figure(*grid)


def uncertainty_grid(r: dict[str, Any], steps: dict[str, dict[str, Any]], config: CellConfig
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """The calibrated cell's predicted sigma (Eq. 29) of the grasp point (mm) and of the rotation (deg), with the
    layout's pixel noise and robot repeatability, for the part shifted over the envelope's x and y (part
    frame): (xs, ys, sigma_mm (ny, nx), sigma_deg (ny, nx)); None when the layout is degenerate.

    The calibration is the session's (the sfi result ``r``, ``intrinsics``, ``part``), where it has one, else the
    config's nominal."""
    layout = config.layout
    camera = CameraModel(**steps["intrinsics"]["camera"]) if "intrinsics" in steps else config.camera.intrinsics
    T_cf_w0 = np.asarray(steps["part"]["T_cf_w0"], dtype=float) if "part" in steps else config.reference.T_cf_w0
    calibrated = {p.get("name"): np.asarray(p["T_cf_si"], dtype=float) for p in r.get("poses") or []}
    T_w0_cf = invert(T_cf_w0)
    T_w0_si = [T_w0_cf @ calibrated.get(p.name, p.T_cf_si) for p in config.measuring_poses]
    observed = [(i, k) for i, pose in enumerate(config.measuring_poses) for k in pose.points]
    points = config.part.points_w
    grasp = config.part.grasp_point_w if config.part.grasp_point_w is not None else points.mean(axis=0)
    sigma_px = layout.sigma_px if layout else 0.1
    rep_mm, rep_deg = (layout.repeatability_mm, layout.repeatability_deg) if layout else (0.05, 0.01)
    half_x, half_y = (layout.envelope.translation_mm[:2] if layout else (50.0, 50.0))
    xs, ys = np.linspace(-half_x, half_x, MAP_STEPS), np.linspace(-half_y, half_y, MAP_STEPS)
    try:
        sigma_mm, sigma_deg = sigma_over_shifts(camera, points, T_w0_si, observed, grasp, xs, ys, sigma_px, rep_mm,
                                                rep_deg)
    except MonoguideError:
        return None
    return xs, ys, sigma_mm, sigma_deg


def sigma_over_shifts(camera: CameraModel, points_w: np.ndarray, T_w0_si: Sequence[np.ndarray],
                      observed: Sequence[tuple[int, int]], grasp_point_w: np.ndarray, xs_mm: np.ndarray,
                      ys_mm: np.ndarray, sigma_px: float, view_sigma_mm: float, view_sigma_deg: float
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Pure math (no I/O, no clock): the predicted sigma (Eq. 29) of the grasp point (mm) and of the rotation
    (deg), ``(len(ys_mm), len(xs_mm))`` each, with the cameras fixed at ``T_w0_si`` (k, 4, 4, in the reference
    part's frame) observing the (view, point) pairs ``observed``, for the part shifted by (x, y, 0) in its own
    frame. Raises the solver's :class:`MonoguideError` (``DegenerateGeometry``, ``PointBehindCamera``) for a
    layout that cannot see the part somewhere on the grid."""
    sigma_mm, sigma_deg = np.empty((len(ys_mm), len(xs_mm))), np.empty((len(ys_mm), len(xs_mm)))
    for iy, y in enumerate(ys_mm):
        for ix, x in enumerate(xs_mm):
            T_w_w0 = make_T(np.eye(3), -np.array([x, y, 0.0]))  # the part moved by (x, y)
            T_w_si = [T_w_w0 @ T for T in T_w0_si]
            cov = observed_covariance(camera, points_w, T_w_si, observed, sigma_px, view_sigma_mm, view_sigma_deg)
            s = pose_sigmas(cov, invert(T_w_si[0]), grasp_point_w)
            sigma_mm[iy, ix], sigma_deg[iy, ix] = s.sigma_trans_mm, s.sigma_rot_deg
    return sigma_mm, sigma_deg


# --- private ---------------------------------------------------------------------------------------


@draw_style
def _uncertainty_figure(xs: np.ndarray, ys: np.ndarray, sigma_mm: np.ndarray, sigma_deg: np.ndarray) -> Figure:
    figure = new_figure(PLAN_SIZE)
    for ax, (values, what, unit) in zip(figure.subplots(1, 2), ((sigma_mm, "grasp point", "mm"),
                                                               (sigma_deg, "rotation", "deg")), strict=True):
        mesh = ax.pcolormesh(xs, ys, values, shading="nearest", cmap="viridis", vmin=float(values.min()),
                             vmax=float(values.max()))
        figure.colorbar(mesh, ax=ax, shrink=0.9).set_label(f"predicted σ of the {what} ({unit})")
        ax.grid(False)
        ax.set_aspect("equal")
        ax.set_xlabel("part shifted in x (part frame, mm)")
        ax.set_ylabel("part shifted in y (part frame, mm)")
        ax.set_title(f"σ of the {what} ({unit})")
    figure.suptitle("The calibrated cell's predicted σ (Eq. 29, pixel noise and robot repeatability of [layout]) "
                    "over the envelope")
    return figure


def _axis_end(T: np.ndarray) -> np.ndarray:
    """Where the camera's line of sight meets the part's plane z = 0 (or 800 mm along it, if it never does)."""
    z = T[:3, 2]
    s = -T[2, 3] / z[2] if abs(z[2]) > 1e-6 and -T[2, 3] / z[2] > 0 else 800.0
    return T[:3, 3] + min(s, 5000.0) * z
