"""What a cycle saw as it went, view by view: the image of each measuring pose visited, the flange pose it was taken
at, where each hole was sought and what was found, and where the cycle failed.

The cycle's task owns one :class:`ViewsSeen` per cycle and hands it to the runner's ``measure``; whatever ends the
cycle, the journal gets from it the images and what was found (docs/journal.md: a failed cycle's ``views`` and
``failure``), so that the operator page can show why a cycle failed. It holds no frame: paths, poses and pixels only.
The hole finder fills it from its worker thread while the robot moves on (a lock).
"""

from __future__ import annotations

import logging
import threading
import time
from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # the states' package stays light (``monoguide status`` loads no numpy)
    import numpy as np

log = logging.getLogger(__name__)

IMAGES_WAIT_S = 10.0  # the longest a cycle waits for its PNGs to be on disk


@dataclass(frozen=True)
class Sought:
    """Where one hole (or mark) was sought in a view: its index and name, the expected image of its centre (full-sensor
    px) and its expected radius (px)."""

    index: int
    name: str
    pixel: tuple[float, float]
    radius_px: float


@dataclass(frozen=True)
class FailedAt:
    """Where the cycle's failure struck, when it was a view's: the pose and the hole or mark not found there."""

    view: str
    point: str | None = None
    expected_px: tuple[float, float] | None = None


@dataclass
class _View:
    view: int
    pose: str
    image: str | None
    T_b_f: list[list[float]]
    expected: tuple[Sought, ...]
    holes: list[dict[str, Any]] = field(default_factory=list)
    marks: list[dict[str, Any]] = field(default_factory=list)


class ViewsSeen:
    """The views of one cycle as they were visited (a view visited again, by the check job's repeated visits, keeps
    its last visit), the PNGs being written, and the first failure met in a view."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._views: dict[int, _View] = {}
        self.images: list[Future[bool]] = []  # the PNGs handed to the image writer (True: written)
        self.failed_at: FailedAt | None = None

    def visited(self, view: int, pose: str, image: str | None, T_b_f: np.ndarray, expected: tuple[Sought, ...],
                writing: Future[bool] | None) -> None:
        """Measuring pose ``view`` (0-based) reached and its frame in hand: ``image`` its PNG's path (None: images not
        kept), ``writing`` the PNG being written."""
        with self._lock:
            self._views[view] = _View(view, pose, image, [[float(v) for v in row] for row in T_b_f], expected)
            if writing is not None:
                self.images.append(writing)

    def found(self, view: int, holes: list[tuple[int, str, tuple[float, float]]],
              marks: list[tuple[int, str, tuple[float, float]]]) -> None:
        """What the finder found in ``view``: (index, name, pixel) per hole and per mark (full-sensor px)."""
        with self._lock:
            seen = self._views.get(view)
            if seen is None:
                return
            seen.holes = [{"point": j, "name": name, "pixel": [float(u), float(v)]} for j, name, (u, v) in holes]
            seen.marks = [{"mark": m, "name": name, "pixel": [float(u), float(v)]} for m, name, (u, v) in marks]

    def failed(self, pose: str, name: str | None = None, expected_px: tuple[float, float] | None = None) -> None:
        """The cycle failed at measuring pose ``pose`` (reaching it, grabbing its frame, or finding hole or mark
        ``name`` expected at ``expected_px``); the first failure wins (a later view's abort comes after it)."""
        with self._lock:
            if self.failed_at is None:
                expected = None if expected_px is None else (float(expected_px[0]), float(expected_px[1]))
                self.failed_at = FailedAt(pose, name, expected)

    def image_paths(self) -> list[str]:
        """Every image written for the cycle, in visiting order."""
        with self._lock:
            return [v.image for v in sorted(self._views.values(), key=lambda v: v.view) if v.image is not None]

    def views(self) -> list[dict[str, Any]]:
        """The views as the journal keeps them (a failed cycle's result ``views``), in pose order."""
        with self._lock:
            return [{"view": v.view, "pose": v.pose, "image": v.image, "T_b_f": v.T_b_f,
                     "holes": list(v.holes), "marks": list(v.marks),
                     "expected": [{"point": s.index, "name": s.name, "pixel": list(s.pixel),
                                   "radius_px": s.radius_px} for s in v.expected]}
                    for v in sorted(self._views.values(), key=lambda v: v.view)]


def wait_images(images: list[Future[bool]], timeout_s: float = IMAGES_WAIT_S) -> bool:
    """Wait (at most ``timeout_s`` in all) until the cycle's PNGs are written; True when all were."""
    deadline = time.monotonic() + timeout_s
    ok = True
    for future in images:
        try:
            ok &= bool(future.result(timeout=max(deadline - time.monotonic(), 0.0)))
        except TimeoutError:
            log.warning("images: still writing after %.0f s", timeout_s)
            return False
    return ok
