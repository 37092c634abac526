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
    ``frame_number`` counts the frames grabbed since open, ``host_time_s`` is ``time.time()`` on arrival,
    ``requested_time_s`` is ``time.time()`` when :meth:`Camera.grab` was called (the frame's exposure
    started after it), ``frame_id`` is the camera's (GenTL producer's) own number of the frame, ``None``
    where it has none."""

    image: np.ndarray
    frame_number: int
    host_time_s: float
    pixel_format: str = "Mono8"
    frame_id: int | None = None
    requested_time_s: float | None = None


@runtime_checkable
class Camera(Protocol):
    """A camera the cycle can open, configure, grab one frame from (with a timeout) and close.

    Failures are :class:`~monoguide.drivers.errors.DeviceError` subclasses: ``DeviceNotFound`` when it is
    absent, ``DeviceTimeout`` when no frame came in time, ``DeviceDisconnected`` when it went away,
    ``DeviceSettingRejected`` when a needed setting is impossible, ``DeviceBusy`` when another client holds
    it. No other exception leaves a camera. Calls from several threads are serialised (a lock per camera).
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
        """One frame whose exposure started after this call (software trigger, or a free-running frame
        past the ones in flight); frames queued or late from earlier requests are never returned."""
        ...

    def close(self) -> None: ...
