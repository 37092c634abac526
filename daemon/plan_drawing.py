"""The picture of a measuring layout (``monoguide plan --layout --out layout.png``), drawn with OpenCV.

Two orthographic views of the reference part's frame, from above (x right, y up) and from the side (x
right, z up): the part's outline through its holes, the holes, where each hole goes at the 64 corners of
the deviation envelope, the planned cameras with their view frusta out to their hole's depth, and the
cell's current camera positions for comparison.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

from monoguide.solver.planning import LayoutAssessment, LayoutRequest

PANEL = (900, 900)  # width, height of one view, px
PAD = 60
WHITE, GREY, DARK = (255, 255, 255), (150, 150, 150), (40, 40, 40)
PLANNED = [(60, 180, 255), (80, 220, 120), (255, 140, 60), (220, 90, 220), (80, 220, 220), (200, 200, 80)]
EXTREME = (0, 200, 255)


def draw_layout(
    request: LayoutRequest,
    plan: LayoutAssessment,
    current: Sequence[np.ndarray] = (),
    title: str = "",
) -> np.ndarray:
    """BGR picture (h, w, 3) of ``plan`` (and the ``current`` camera poses ``T_w0_si``, grey)."""
    points = np.asarray(request.points_w, dtype=float)
    corners = request.deviations()[:64]
    extremes = np.einsum("kab,nb->kna", corners[:, :3, :3], points) + corners[:, None, :3, 3]  # (64, n, 3)
    frusta = [_frustum(request, T, plan.depth_mm[i].mean()) for i, T in enumerate(plan.T_w0_si)]
    current_centres = np.array([T[:3, 3] for T in current]).reshape(-1, 3)
    panels = []
    for axes, label in (((0, 1), "from above: x right, y up (mm, part frame)"),
                        ((0, 2), "from the side: x right, z up (mm, part frame)")):
        every = np.vstack([points, extremes.reshape(-1, 3), *frusta, current_centres])[:, axes]
        to_px = _mapping(every)
        canvas = np.full((PANEL[1], PANEL[0], 3), 24, np.uint8)
        placed: list[tuple[int, int]] = []  # label positions so far: labels that would overlap are stacked
        outline = to_px(points[:, axes])
        hull = cv2.convexHull(outline.astype(np.int32))
        cv2.polylines(canvas, [hull], True, GREY, 1, cv2.LINE_AA)
        for i in range(len(points)):
            for p in to_px(extremes[:, i, axes]):
                cv2.circle(canvas, tuple(int(v) for v in p), 2, EXTREME, -1, cv2.LINE_AA)
        for i, corners_w in enumerate(frusta):
            colour = PLANNED[i % len(PLANNED)]
            apex, rim = to_px(corners_w[:1, axes])[0], to_px(corners_w[1:, axes])
            for q in rim:
                cv2.line(canvas, _pt(apex), _pt(q), colour, 1, cv2.LINE_AA)
            cv2.polylines(canvas, [rim.astype(np.int32)], True, colour, 1, cv2.LINE_AA)
            cv2.circle(canvas, _pt(apex), 6, colour, -1, cv2.LINE_AA)
            _label(canvas, f"S{i + 1}", _pt(apex + 10), colour, 0.5, placed)
        for i, c in enumerate(current_centres):
            p = _pt(to_px(c[None, axes])[0])
            cv2.drawMarker(canvas, p, GREY, cv2.MARKER_TILTED_CROSS, 12, 2)
            _label(canvas, f"now {i + 1}", (p[0] + 8, p[1] + 16), GREY, 0.4, placed)
        for name, p in zip(request.names(), outline, strict=True):
            cv2.circle(canvas, _pt(p), 5, WHITE, -1, cv2.LINE_AA)
            _label(canvas, name, _pt(p + np.array([8, -8])), WHITE, 0.5, placed)
        cv2.putText(canvas, label, (12, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.55, WHITE, 1, cv2.LINE_AA)
        panels.append(canvas)
    picture = np.hstack(panels)
    legend = [
        title,
        "coloured: planned cameras and their view frusta to the hole's depth; grey x: the cell's current cameras",
        "white: holes; orange dots: where the holes go at the 64 corners of the envelope "
        + request.envelope.describe(),
    ]
    footer = np.full((24 * len(legend) + 12, picture.shape[1], 3), 24, np.uint8)
    for k, text in enumerate(legend):
        cv2.putText(footer, text, (12, 24 * (k + 1)), cv2.FONT_HERSHEY_SIMPLEX, 0.55, WHITE, 1, cv2.LINE_AA)
    return np.vstack([picture, footer])


def _frustum(request: LayoutRequest, T_w0_c: np.ndarray, depth_mm: float) -> np.ndarray:
    """Camera centre and the four image corners' lines of sight at ``depth_mm``, (5, 3) in the part frame."""
    cam = request.camera
    corners_px = np.array([[-0.5, -0.5], [cam.width - 0.5, -0.5], [cam.width - 0.5, cam.height - 0.5],
                           [-0.5, cam.height - 0.5]])
    xy = cam.undistort_pixels(corners_px)
    rim_c = np.column_stack([xy * depth_mm, np.full(4, depth_mm)])
    rim_w = rim_c @ T_w0_c[:3, :3].T + T_w0_c[:3, 3]
    return np.vstack([T_w0_c[:3, 3], rim_w])


def _mapping(every: np.ndarray):
    low, high = every.min(axis=0), every.max(axis=0)
    scale = min((PANEL[0] - 2 * PAD) / max(high[0] - low[0], 1.0), (PANEL[1] - 2 * PAD) / max(high[1] - low[1], 1.0))
    offset = np.array([PANEL[0], PANEL[1]]) / 2.0 - scale * np.array([(low[0] + high[0]) / 2, -(low[1] + high[1]) / 2])

    def to_px(xy: np.ndarray) -> np.ndarray:
        return np.column_stack([xy[:, 0] * scale, -xy[:, 1] * scale]) + offset

    return to_px


def _label(canvas: np.ndarray, text: str, at: tuple[int, int], colour: tuple[int, int, int], scale: float,
           placed: list[tuple[int, int]]) -> None:
    """Write ``text`` at ``at``, moved down a line while it would overlap a label already ``placed`` (in the
    side view cameras and holes that differ only in y coincide)."""
    x, y = at
    while any(abs(x - px) < 48 and abs(y - py) < 15 for px, py in placed):
        y += 16
    placed.append((x, y))
    cv2.putText(canvas, text, (x, y), cv2.FONT_HERSHEY_SIMPLEX, scale, colour, 1, cv2.LINE_AA)


def _pt(p: np.ndarray) -> tuple[int, int]:
    return round(float(p[0])), round(float(p[1]))
