"""The drawing of a measuring layout (``monoguide plan --layout --out layout.png``), drawn with matplotlib.

Two views of the reference part's frame to scale, in mm, from above (x right, y up) and from the side (x
right, z up): the part's outline through its holes, the holes, where each hole goes at the 64 corners of the
deviation envelope, the planned cameras with their view frusta out to their hole's depth, and the cell's
current camera positions for comparison.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from monoguide.daemon.figures import REFERENCE, SERIES, draw_style, figure_legend, label_points, new_figure, outline
from monoguide.solver.planning import LayoutAssessment, LayoutRequest

if TYPE_CHECKING:
    from matplotlib.figure import Figure

LAYOUT_SIZE = (1600, 820)  # width, height px of the drawing
EXTREME = "tab:orange"  # the holes at the envelope's corners


@draw_style
def draw_layout(
    request: LayoutRequest,
    plan: LayoutAssessment,
    current: Sequence[np.ndarray] = (),
    title: str = "",
) -> Figure:
    """The drawing of ``plan`` (and of the ``current`` camera poses ``T_w0_si``, grey), :data:`LAYOUT_SIZE`."""
    points = np.asarray(request.points_w, dtype=float)
    corners = request.deviations()[:64]
    extremes = np.einsum("kab,nb->kna", corners[:, :3, :3], points) + corners[:, None, :3, 3]  # (64, n, 3)
    frusta = [_frustum(request, T, plan.depth_mm[i].mean()) for i, T in enumerate(plan.T_w0_si)]
    current_centres = np.array([T[:3, 3] for T in current]).reshape(-1, 3)
    figure = new_figure(LAYOUT_SIZE)
    panels = figure.subplots(1, 2)
    for ax, (a, b, view) in zip(panels, ((0, 1, "from above: x right, y up"), (0, 2, "from the side: x right, z up")),
                                strict=True):
        every = np.vstack([points, extremes.reshape(-1, 3), *frusta, current_centres])[:, [a, b]]
        span = float(np.ptp(every, axis=0).max())
        if len(points) >= 3:
            hull = outline(points[:, [a, b]])
            ax.fill(hull[:, 0], hull[:, 1], facecolor="0.94", edgecolor=REFERENCE, label="part outline (holes)")
        ax.plot(extremes[..., a].ravel(), extremes[..., b].ravel(), ".", color=EXTREME, markersize=3,
                label="holes at the 64 corners of the envelope")
        for i, corners_w in enumerate(frusta):
            colour = SERIES[i % len(SERIES)]
            apex, rim = corners_w[0], corners_w[1:]
            for q in rim:
                ax.plot([apex[a], q[a]], [apex[b], q[b]], "-", color=colour, linewidth=0.8)
            ring = np.vstack([rim, rim[:1]])
            ax.plot(ring[:, a], ring[:, b], "-", color=colour, linewidth=0.8)
            ax.plot(apex[a], apex[b], "o", color=colour, markersize=7,
                    label=f"S{i + 1}: planned camera, view frustum to its hole's depth")
        if len(current_centres):
            ax.plot(current_centres[:, a], current_centres[:, b], "X", color="0.5", markersize=8,
                    label="the cell's current cameras")
        cameras = np.vstack([np.array([f[0] for f in frusta]).reshape(-1, 3), current_centres])
        names = [f"S{i + 1}" for i in range(len(frusta))] + [f"now {i + 1}" for i in range(len(current_centres))]
        label_points(ax, names, cameras[:, [a, b]], "0.15", span)  # a planned and a current camera may coincide
        ax.plot(points[:, a], points[:, b], "o", color="black", markersize=5, label="featured hole")
        label_points(ax, request.names(), points[:, [a, b]], "black", span)
        ax.margins(0.06)
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel("x (part frame, mm)")
        ax.set_ylabel(f"{'yz'[b - 1]} (part frame, mm)")
        ax.set_title(view)
    figure_legend(figure, *panels, columns=3)
    figure.suptitle(f"{title or 'planned measuring poses'} (to scale, mm); the envelope: "
                    f"{request.envelope.describe()}")
    return figure


def _frustum(request: LayoutRequest, T_w0_c: np.ndarray, depth_mm: float) -> np.ndarray:
    """Camera centre and the four image corners' lines of sight at ``depth_mm``, (5, 3) in the part frame."""
    cam = request.camera
    corners_px = np.array([[-0.5, -0.5], [cam.width - 0.5, -0.5], [cam.width - 0.5, cam.height - 0.5],
                           [-0.5, cam.height - 0.5]])
    xy = cam.undistort_pixels(corners_px)
    rim_c = np.column_stack([xy * depth_mm, np.full(4, depth_mm)])
    rim_w = rim_c @ T_w0_c[:3, :3].T + T_w0_c[:3, 3]
    return np.vstack([T_w0_c[:3, 3], rim_w])
