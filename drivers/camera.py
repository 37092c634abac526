"""The camera port: what the cycle needs from the flange camera, whichever camera it is."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np


@dataclass(frozen=True)
class CameraIdentity:
    vendor: str
    model: str
    serial: str
    user_name: str | None = None
    version: str | None = None


@dataclass(frozen=True)
class CameraSettings:
    """What the cell sets on the camera. ``None`` leaves the camera's own value. ``region`` is
    (offset_x, offset_y, width, height) in px."""

    pixel_format: str = "Mono8"
    exposure_us: float | None = None
    gain_db: float | None = None
    region: tuple[int, int, int, int] | None = None


@dataclass(frozen=True)
class Frame:
    """One grabbed image: ``image`` (height, width) uint8 for Mono8 (uint16 for deeper mono formats),
    ``frame_number`` counts the frames grabbed since open, ``host_time_s`` is ``time.time()`` on arrival."""

    image: np.ndarray
    frame_number: int
    host_time_s: float
    pixel_format: str = "Mono8"


@runtime_checkable
class Camera(Protocol):
    """A camera the cycle can open, configure, grab one frame from (with a timeout) and close.

    Failures are :class:`~monoguide.drivers.errors.DeviceError` subclasses: ``DeviceNotFound`` when it is
    absent, ``DeviceTimeout`` when no frame came in time, ``DeviceDisconnected`` when it went away,
    ``DeviceSettingRejected`` when a needed setting is impossible.
    """

    def open(self) -> CameraIdentity:
        """Connect; returns the camera's identity."""
        ...

    @property
    def identity(self) -> CameraIdentity | None: ...

    def configure(self, settings: CameraSettings) -> None:
        """Apply ``settings``; optional features the camera lacks are logged and skipped."""
        ...

    def grab(self, timeout_s: float) -> Frame:
        """One frame exposed after this call (software trigger, or the next free-running frame)."""
        ...

    def close(self) -> None: ...
