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

PREVIEW_WIDTH = 1232
JPEG_QUALITY = 85
DECODED_KEPT = 4
CROP_MIN_PX, CROP_MAX_PX = 48, 600
MAX_SIDE_PX = 100_000


class ImageGone(LookupError):
    """The view has no image file (never written, pruned, or outside the images folder); the message says which."""


def image_file(state_dir: Path, number: int, view: int, stored: str | None, pruned: bool) -> Path:
    """The stored file of ``view`` (0-based) of cycle ``number``: ``stored`` as its row names it (None: none)."""
    if stored is None:
        raise ImageGone(f"cycle {number} has no image of view {view + 1}")
    if pruned:
        raise ImageGone(f"cycle {number}'s images were pruned (the [service] size or age limit)")
    images = (Path(state_dir) / "images").resolve()
    try:
        path = Path(stored)
        path = (path if path.is_absolute() else Path(state_dir) / path).resolve()
    except (OSError, ValueError, RuntimeError):  # a name the file system cannot take, a loop of links
        path = None
    if path is None or not path.is_relative_to(images) or path.suffix.lower() != ".png":
        raise ImageGone(f"cycle {number} view {view + 1}: the journal names a file outside the images folder")
    if not path.is_file():
        raise ImageGone(f"cycle {number} view {view + 1}: the image file is gone")
    return path


def png_size(path: Path) -> tuple[int, int] | None:
    """Width and height from a PNG's header (None when it is not a PNG's)."""
    try:
        with open(path, "rb") as file:
            head = file.read(24)
    except OSError:
        return None
    if len(head) < 24 or head[:8] != b"\x89PNG\r\n\x1a\n" or head[12:16] != b"IHDR":
        return None
    width, height = int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")
    return (width, height) if 0 < width <= MAX_SIDE_PX and 0 < height <= MAX_SIDE_PX else None


def preview(path: Path) -> bytes:
    """The view scaled to :data:`PREVIEW_WIDTH` px wide (never up), as JPEG."""
    image = _decoded(path)
    height, width = image.shape[:2]
    if width > PREVIEW_WIDTH:
        image = cv2.resize(image, (PREVIEW_WIDTH, max(round(height * PREVIEW_WIDTH / width), 1)),
                           interpolation=cv2.INTER_AREA)
    return _encoded(path, ".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY], "a preview")


def crop_box(centre_px: tuple[float, float], radius_px: float, width: int, height: int) -> tuple[int, int, int, int]:
    """x, y, w, h of the square around a hole (about 8 radii), inside the image."""
    side = int(min(max(8.0 * radius_px, CROP_MIN_PX), CROP_MAX_PX))
    x0 = int(min(max(round(centre_px[0] - side / 2), 0), max(width - side, 0)))
    y0 = int(min(max(round(centre_px[1] - side / 2), 0), max(height - side, 0)))
    return x0, y0, min(side, width), min(side, height)


def crop(path: Path, box: tuple[int, int, int, int]) -> bytes:
    x, y, w, h = box
    image = _decoded(path)[y:y + h, x:x + w]
    if image.size == 0:  # the file is smaller than the camera's image the row says it is
        raise ImageGone(f"{path.name}: the hole's square lies outside this image")
    return _encoded(path, ".png", image, [cv2.IMWRITE_PNG_COMPRESSION, 1], "the hole's square")


# --- private ------------------------------------------------------------------------------------

_decode_lock = threading.Lock()


def _decoded(path: Path) -> np.ndarray:
    try:
        stat = os.stat(path)
    except OSError as exc:
        raise ImageGone(f"{path.name}: the image file is gone ({exc.strerror})") from None
    with _decode_lock:
        return _decode(str(path), stat.st_mtime_ns, stat.st_size)


@functools.lru_cache(maxsize=DECODED_KEPT)
def _decode(path: str, _mtime_ns: int, _size: int) -> np.ndarray:
    try:
        image = cv2.imread(path, cv2.IMREAD_UNCHANGED)
    except cv2.error:
        image = None
    if image is None or image.ndim not in (2, 3) or image.size == 0:
        raise ImageGone(f"{Path(path).name}: not a readable PNG")
    if image.dtype != np.uint8:  # 10-16 bit frames: shown as 8 bit
        image = cv2.convertScaleAbs(image, alpha=255.0 / max(float(image.max()), 1.0))
    return image


def _encoded(path: Path, kind: str, image: np.ndarray, options: list[int], what: str) -> bytes:
    if image.ndim == 3 and image.shape[2] == 4:  # RGBA: shown without its alpha
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
    try:
        ok, data = cv2.imencode(kind, image, options)
    except cv2.error:
        ok = False
    if not ok:
        raise ImageGone(f"{path.name}: cannot encode {what}")
    return bytes(data.tobytes())
