"""A row of before keeps where the hole was sought only in its error message: every refusal the hole finder and the
mark finder really raise (on seeded synthetic images), prefixed as the cycle prefixes them, is read back to the
pose, the hole (or mark) and the pixel the finder was given, and drawn in that view."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from helpers.repository import SIM_CELL

from monoguide.daemon.config import load_cell_config
from monoguide.daemon.cycle._marks import find_mark
from monoguide.daemon.service import JournalRow
from monoguide.daemon.web._overlay import view_marks
from monoguide.daemon.web._rows import cycle_row
from monoguide.daemon.web._sightings import failure_of
from monoguide.solver.errors import MonoguideError
from monoguide.solver.holes import measure_hole
from monoguide.solver.planning.search import HoleSearch

RADIUS_PX = 12.0


def _disc(image: np.ndarray, centre: tuple[float, float], value: int) -> None:
    shift = 8
    cv2.circle(image, (round(centre[0] * 2**shift), round(centre[1] * 2**shift)), round(RADIUS_PX * 2**shift), value,
               -1, cv2.LINE_AA, shift)


def _frame(*discs: tuple[tuple[float, float], int], grey: int = 170) -> np.ndarray:
    image = np.full((300, 400), grey, np.uint8)
    for centre, value in discs:
        _disc(image, centre, value)
    return image


# each refusal of the hole finder: the image, where the hole is expected
REFUSALS = {
    "HoleNotFound": (_frame(), (200.37, 150.82)),
    "LowContrast": (_frame(((200, 150), 163)), (201.31, 149.64)),
    "HoleAmbiguous": (_frame(((178, 150), 30), ((226, 152), 30)), (202.08, 151.43)),
    "ImageSaturated": (_frame(grey=255), (200.52, 150.47)),
    "HoleCutByBorder": (_frame(((5, 150), 30)), (8.44, 150.18)),
}


def _row(message: str, code: str) -> JournalRow:
    return JournalRow(number=7, started_at=0.0, finished_at=4.0, job=1, part_tag=7, status="error", error_code=code,
                      plc_code=301, error_message=message, record=None, result=None, timings_s={},
                      poses_at_capture=[], image_paths=[], images_pruned_at=None)


@pytest.mark.parametrize("refusal", sorted(REFUSALS))
def test_each_refusal_of_the_hole_finder_is_read_back(refusal: str) -> None:
    image, expected = REFUSALS[refusal]
    with pytest.raises(MonoguideError) as raised:
        measure_hole(image, expected, RADIUS_PX)
    assert type(raised.value).__name__ == refusal
    row = cycle_row(_row(f"S2, P2: {raised.value.message}", raised.value.code))  # as the cycle prefixes it
    failure = failure_of(row)
    assert failure is not None and failure.from_message and not failure.is_mark
    assert (failure.view, failure.point) == ("S2", "P2")
    assert failure.expected_px == (round(expected[0], 1), round(expected[1], 1)) and failure.radius_px == RADIUS_PX
    views = view_marks(row, load_cell_config(SIM_CELL).for_job(1)).views
    lost = [(v.index, h.point, h.expected_px) for v in views for h in v.holes if h.missing]
    assert lost == [(1, 1, failure.expected_px)]


def test_a_mark_the_mark_finder_did_not_find_is_read_back() -> None:
    search = HoleSearch((231.6, 140.2), RADIUS_PX, (150, 60, 160, 160), 3 * RADIUS_PX)
    with pytest.raises(MonoguideError) as raised:
        find_mark(_frame(), search, (0.0, 0.0), (0, 0), None, "S3, mark M2")
    failure = failure_of(cycle_row(_row(raised.value.message, raised.value.code)))
    assert failure is not None and failure.is_mark and (failure.view, failure.point) == ("S3", "M2")
    assert failure.expected_px == (232.0, 140.0)  # the mark finder says where to the pixel


def test_a_message_that_says_nowhere_is_no_failure_place() -> None:
    assert failure_of(cycle_row(_row("camera, frame 3: timed out after 2.0 s", "DEVICE_TIMEOUT"))) is None
