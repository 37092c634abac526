"""The cycle's images written as PNGs off the cycle's path, by a worker thread of their own.

The last view's image would otherwise sit between the last frame and the offset write: the cycle hands each
frame over and waits for the files only after the robot acknowledged the offset (at most
:data:`~monoguide.daemon.cycle._seen.IMAGES_WAIT_S`, :func:`~monoguide.daemon.cycle._seen.wait_images`).
"""

from __future__ import annotations

import logging
import re
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

import cv2
import numpy as np

log = logging.getLogger(__name__)

PNG_COMPRESSION = 1  # fast: a 5 MP frame in ~0.1 s


def image_path(images_dir: Path | str | None, pose_name: str) -> Path | None:
    """Where the image of measuring pose ``pose_name`` goes (None without an images folder)."""
    if images_dir is None:
        return None
    return Path(images_dir) / f"{re.sub(r'[^A-Za-z0-9_.-]', '_', pose_name)}.png"


class ImageWriter:
    """One worker thread writing PNGs; :meth:`close` finishes what it was given and ends it."""

    def __init__(self) -> None:
        self._pool = ThreadPoolExecutor(1, thread_name_prefix="monoguide-images")

    def submit(self, path: Path, image: np.ndarray, name: str) -> Future[bool]:
        return self._pool.submit(_save_png, path, image, name)

    def close(self) -> None:
        self._pool.shutdown(wait=True)


def _save_png(path: Path, image: np.ndarray, name: str) -> bool:
    """``image`` as PNG at ``path``; False (and a warning) when it cannot."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        if cv2.imwrite(str(path), image, [cv2.IMWRITE_PNG_COMPRESSION, PNG_COMPRESSION]):
            return True
    except (OSError, cv2.error) as exc:
        log.warning("cannot save the image of %s at %s: %s", name, path, exc)
        return False
    log.warning("cannot save the image of %s at %s", name, path)
    return False
