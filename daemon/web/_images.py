"""A cycle's images, addressed by cycle and view only: the file is the one the journal's row names, and it is
served only when it lies inside ``<state dir>/images`` once every link is resolved — nothing from a URL ever
becomes a path, and a journal row naming ``/etc/passwd`` serves nothing.

``preview`` is the view scaled down (JPEG, :data:`PREVIEW_WIDTH` px wide) for the page; ``crop`` a full-resolution
square around a hole (PNG); ``original`` the stored PNG itself for download. The last few decoded images are
kept (:data:`DECODED_KEPT`, ~5 MB each for a 5 MP view), since a view's preview and its holes' crops come one
after another.
"""

from __future__ import annotations

import functools
import os
import threading
from pathlib import Path

import cv2
import numpy as np

from monoguide.daemon.service import JournalRow

PREVIEW_WIDTH = 1232
JPEG_QUALITY = 85
DECODED_KEPT = 4
CROP_MIN_PX, CROP_MAX_PX = 48, 600


class ImageGone(LookupError):
    """The view has no image file (never written, pruned, or outside the images folder); the message says which."""


def image_file(state_dir: Path, row: JournalRow, view: int) -> Path:
    """The stored file of ``view`` (0-based) of the cycle ``row``."""
    if not 0 <= view < len(row.image_paths):
        raise ImageGone(f"cycle {row.number} has no image of view {view + 1} ({len(row.image_paths)} stored)")
    if row.images_pruned_at is not None:
        raise ImageGone(f"cycle {row.number}'s images were pruned (the [service] size or age limit)")
    images = (Path(state_dir) / "images").resolve()
    stored = Path(row.image_paths[view])
    path = (stored if stored.is_absolute() else Path(state_dir) / stored).resolve()
    if not path.is_relative_to(images) or path.suffix.lower() != ".png":
        raise ImageGone(f"cycle {row.number} view {view + 1}: the journal names a file outside the images folder")
    if not path.is_file():
        raise ImageGone(f"cycle {row.number} view {view + 1}: the image file is gone")
    return path


def preview(path: Path) -> bytes:
    """The view scaled to :data:`PREVIEW_WIDTH` px wide (never up), as JPEG."""
    image = _decoded(path)
    height, width = image.shape[:2]
    if width > PREVIEW_WIDTH:
        image = cv2.resize(image, (PREVIEW_WIDTH, round(height * PREVIEW_WIDTH / width)), interpolation=cv2.INTER_AREA)
    ok, data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    if not ok:
        raise ImageGone(f"{path.name}: cannot encode a preview")
    return data.tobytes()


def crop_box(centre_px: tuple[float, float], radius_px: float, width: int, height: int) -> tuple[int, int, int, int]:
    """x, y, w, h of the square around a hole (about 8 radii), inside the image."""
    side = int(min(max(8.0 * radius_px, CROP_MIN_PX), CROP_MAX_PX))
    x0 = int(min(max(round(centre_px[0] - side / 2), 0), max(width - side, 0)))
    y0 = int(min(max(round(centre_px[1] - side / 2), 0), max(height - side, 0)))
    return x0, y0, min(side, width), min(side, height)


def crop(path: Path, box: tuple[int, int, int, int]) -> bytes:
    x, y, w, h = box
    image = _decoded(path)[y:y + h, x:x + w]
    ok, data = cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, 1])
    if not ok or image.size == 0:
        raise ImageGone(f"{path.name}: cannot cut the hole's square")
    return data.tobytes()


# --- private ------------------------------------------------------------------------------------

_decode_lock = threading.Lock()


def _decoded(path: Path) -> np.ndarray:
    stat = os.stat(path)
    with _decode_lock:
        return _decode(str(path), stat.st_mtime_ns, stat.st_size)


@functools.lru_cache(maxsize=DECODED_KEPT)
def _decode(path: str, _mtime_ns: int, _size: int) -> np.ndarray:
    image = cv2.imread(path, cv2.IMREAD_UNCHANGED)
    if image is None:
        raise ImageGone(f"{Path(path).name}: not a readable PNG")
    if image.dtype != np.uint8:  # 10-16 bit frames: shown as 8 bit
        image = cv2.convertScaleAbs(image, alpha=255.0 / max(float(image.max()), 1.0))
    return image
