"""Where the cycle seeks each fixed reference mark of a measuring pose, and finding it (docs/cycle-marks.md).

A mark is fixed in the cell: it is sought in a region about where the calibrated camera pose puts it,
:data:`MARK_SEARCH_PX` beyond its radius, and its imaged circle's centre is corrected for perspective with that same
pose (all the correction needs). The hole finder finds it as it finds a hole; its size tells it from the holes.
"""

from __future__ import annotations

import numpy as np

from monoguide.daemon.config import CellConfig, MeasuringPose
from monoguide.drivers.errors import ConfigError
from monoguide.solver import frames
from monoguide.solver.errors import MarkNotFound, MonoguideError
from monoguide.solver.holes import measure_hole, perspective_correction, reach
from monoguide.solver.planning.search import HoleSearch, hole_search

# how far from where the calibration puts it a mark is sought (px, beyond its radius): 1.4 deg or 16 mm of the
# camera at 650 mm on the simulated roof cell's lens, so that a camera knocked that far is measured (and refused,
# CALIBRATION_SUSPECT), not lost (MARK_NOT_FOUND, refused all the same); a small region keeps each mark ~10 ms
MARK_SEARCH_PX = 60.0
MARK_FINDERS = 2  # threads finding a view's marks beside its holes (the last view's are on the overhead's path)


def plan_marks(config: CellConfig, pose: MeasuringPose) -> tuple[list[HoleSearch], list[tuple[float, float]]]:
    """The search of each mark ``pose`` lists and its perspective shift (imaged circle's centre minus the image of the
    mark's centre); :class:`ConfigError` naming a mark its camera does not see."""
    camera, T_c_cf = config.camera.intrinsics, frames.invert(pose.T_cf_si)
    searches, shifts = [], []
    for m in pose.marks:
        mark = config.reference_marks[m]
        search = hole_search(camera, T_c_cf, mark.position_cf, mark.normal_cf, mark.radius_mm, np.eye(4)[None],
                             margin_px=MARK_SEARCH_PX)
        depth = float(frames.transform_points(T_c_cf, mark.position_cf[None])[0, 2])
        if search is None or depth <= 0 or not camera.in_image(np.array([search.expected_px]), search.radius_px)[0]:
            raise ConfigError(f"{config.path}: measuring pose {pose.name} lists mark {mark.name}, but its camera does "
                              f"not see it (position_cf {np.round(mark.position_cf, 1).tolist()}, depth {depth:.0f} "
                              "mm): check [[reference_marks]] and the pose's marks")
        searches.append(search)
        shift = perspective_correction(camera, T_c_cf, mark.position_cf, mark.normal_cf, mark.radius_mm)
        shifts.append((float(shift[0]), float(shift[1])))
    return searches, shifts


def find_mark(image: np.ndarray, search: HoleSearch, shift: tuple[float, float], offset: tuple[int, int],
              bits: int | None, what: str) -> tuple[float, float]:
    """The image of a mark's centre (full-sensor px; ``offset`` the camera region's origin), or
    :class:`MarkNotFound` naming ``what`` (pose and mark). A mark's rim is long (twice a hole's, ~200 edge points):
    its ellipse fit alone is within 0.01 px of the rendered truth, the photometric refinement (7 ms a mark) adds
    nothing."""
    (ex, ey), (rx, ry, rw, rh) = search.expected_px, search.roi
    # only the part of the frame the finder can reach (the same centre, without frame-sized arrays: 4 ms a mark)
    x0, y0, x1, y1 = reach(image.shape, (rx - offset[0], ry - offset[1], rw, rh), search.radius_px)
    image, ox, oy = image[y0:y1, x0:x1], offset[0] + x0, offset[1] + y0
    try:
        mark = measure_hole(image, (ex - ox, ey - oy), search.radius_px, (rx - ox, ry - oy, rw, rh),
                            max_offset_px=search.max_offset_px, bit_depth=bits, photometric=False)
    except MonoguideError as exc:
        raise MarkNotFound(f"{what}: not found within {MARK_SEARCH_PX:g} px of where the calibration puts it "
                           f"({ex:.0f}, {ey:.0f}) px: {exc.code}: {exc.message} (the finder's px are of its window "
                           f"at ({ox}, {oy})); is something (a part out of place, a cable) hiding it, or has the "
                           "camera moved? Nothing is written to the robot.") from exc
    return float(mark.center[0]) + ox - shift[0], float(mark.center[1]) + oy - shift[1]
