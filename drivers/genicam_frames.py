"""Fresh frames from a GenTL stream: every grab returns a frame whose exposure started after the request.

A GenTL producer hands out filled buffers in the order the camera sent them. Left alone, the stream
holds frames that are not this request's: frames queued before it (the previous pose), a late frame of
an earlier trigger that timed out, and, when the camera runs free, the frame(s) in flight whose exposure
began while the robot was still moving. :class:`FreshFrames` sorts them out:

* **flush**: every buffer already delivered when the request comes is dropped (and re-queued);
* **software trigger**: the frame answering this trigger is the first to arrive after the late frames of
  earlier, still unanswered triggers; those are counted and dropped. Where the producer numbers its
  frames (GenTL ``frame_id``), the id must also lie past them. If a grab times out while it was waiting
  past an earlier unanswered trigger (a trigger or its frame was lost: the count cannot be trusted), the
  acquisition is stopped, which discards the producer's queue, and the next grab starts it afresh;
* **free-running**: the next ``in_flight`` frames to arrive after the flush may have started exposing
  before the request and are dropped (default 2: one being read out while the next is exposed, as
  cameras with overlapping readout do); with frame ids, the accepted frame's id must also be at least
  ``in_flight + 1`` past the last frame seen at the request.
* an acquisition started by this grab only yields frames exposed after the request.

Blocking calls; the caller holds the camera's lock. Works on anything with the part of harvesters'
``ImageAcquirer`` used here (``is_acquiring``, ``start``, ``stop``, ``try_fetch``).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from genicam import gentl

from monoguide.drivers.errors import DeviceSettingRejected, DeviceTimeout

log = logging.getLogger(__name__)

MONO_DTYPES = {"Mono8": np.uint8, "Mono10": np.uint16, "Mono12": np.uint16, "Mono16": np.uint16}
FLUSH_LIMIT = 1000  # a stream that never runs dry while flushing is a fault, not a loop
FLUSH_POLL_S = 0.0001


@dataclass(frozen=True)
class FreshFrame:
    """One accepted frame: ``image`` (height, width), the producer's ``frame_id`` (``None`` where it has
    none), ``requested_time_s`` and ``received_time_s`` (``time.time()``), and how many stale frames were
    ``dropped`` on the way."""

    image: np.ndarray
    pixel_format: str
    frame_id: int | None
    requested_time_s: float
    received_time_s: float
    dropped: int


class FreshFrames:
    """Grabs frames exposed after the request from ``acquirer``. ``trigger`` fires the camera's software
    trigger (``None``: the camera runs free). ``name`` names the camera in messages."""

    def __init__(self, acquirer: Any, name: str, trigger: Callable[[], None] | None = None,
                 in_flight: int = 2) -> None:
        if isinstance(in_flight, bool) or not isinstance(in_flight, int) or in_flight < 1:
            raise DeviceSettingRejected(f"{name}: in_flight_frames {in_flight!r} must be a whole number >= 1")
        self._acquirer = acquirer
        self._name = name
        self._trigger = trigger
        self._in_flight = in_flight
        self._last_id: int | None = None
        self._unanswered = 0  # triggers whose frame has not arrived (their frames are late, not ours)

    @property
    def triggered(self) -> bool:
        return self._trigger is not None

    def grab(self, timeout_s: float) -> FreshFrame:
        """The first frame exposed after this call, within ``timeout_s``; else :class:`DeviceTimeout`."""
        requested = time.time()
        deadline = time.monotonic() + timeout_s
        acquirer = self._acquirer
        dropped = 0
        if not acquirer.is_acquiring():
            acquirer.start()  # nothing in this stream was exposed before the request
            self._last_id, self._unanswered, to_skip = None, 0, 0
        else:
            dropped = self._flush()
            to_skip = self._unanswered if self._trigger is not None else self._in_flight
        last_at_request, window = self._last_id, to_skip
        if self._trigger is not None:
            self._trigger()
            self._unanswered += 1
        while (remaining := deadline - time.monotonic()) > 0:
            buffer = acquirer.try_fetch(timeout=remaining)
            if buffer is None:
                break
            with buffer:
                frame_id = _frame_id(buffer)
                self._answered()
                if to_skip > 0 or _before(frame_id, last_at_request, window):
                    to_skip = max(0, to_skip - 1)
                    dropped += 1
                    self._note(frame_id)
                    log.info("%s: dropped frame %s (exposed before the request)", self._name, frame_id)
                    continue
                self._note(frame_id)
                image, pixel_format = _copy_image(buffer, self._name)
            return FreshFrame(image, pixel_format, frame_id, requested, time.time(), dropped)
        self._timed_out(window)
        raise DeviceTimeout(f"{self._name}: no frame within {timeout_s:g} s"
                            + (f" ({dropped} stale frame(s) dropped)" if dropped else ""))

    # --- private -------------------------------------------------------------------------------

    def _flush(self) -> int:
        """Drop every buffer already delivered; returns how many."""
        for count in range(FLUSH_LIMIT):
            buffer = self._acquirer.try_fetch(timeout=FLUSH_POLL_S)
            if buffer is None:
                if count:
                    log.info("%s: flushed %d queued frame(s) before the request", self._name, count)
                return count
            with buffer:
                self._note(_frame_id(buffer))
                self._answered()
        raise DeviceTimeout(f"{self._name}: the stream did not run dry after {FLUSH_LIMIT} frames")

    def _answered(self) -> None:
        if self._trigger is not None and self._unanswered > 0:
            self._unanswered -= 1

    def _note(self, frame_id: int | None) -> None:
        if frame_id is not None:
            self._last_id = frame_id

    def _timed_out(self, window: int) -> None:
        if self._trigger is None or window == 0:
            return  # this trigger's frame may still come late: counted, it will be dropped
        # a second timeout while waiting past an earlier trigger's frame: that trigger (or this one) was lost
        # and the count cannot be trusted; stopping discards the producer's queue, the next grab restarts
        log.warning("%s: triggers unanswered twice in a row; stopping the acquisition to discard their frames",
                    self._name)
        self._acquirer.stop()
        self._last_id, self._unanswered = None, 0


def _before(frame_id: int | None, last_at_request: int | None, window: int) -> bool:
    """Whether the producer's numbering puts ``frame_id`` among the ``window`` frames that were in flight
    (or late) at the request. Ids at or below the last one seen mean the numbering wrapped or restarted:
    the count decides alone."""
    if frame_id is None or last_at_request is None:
        return False
    return last_at_request < frame_id <= last_at_request + window


def _frame_id(buffer: Any) -> int | None:
    try:
        frame_id = buffer.module.frame_id
    except (gentl.GenericException, AttributeError):
        return None
    return int(frame_id) if isinstance(frame_id, int) else None


def _copy_image(buffer: Any, name: str) -> tuple[np.ndarray, str]:
    component = buffer.payload.components[0]
    fmt = component.data_format
    if fmt not in MONO_DTYPES:
        raise DeviceSettingRejected(f"{name}: delivered {fmt}, expected a mono format ({sorted(MONO_DTYPES)})")
    data = np.asarray(component.data).view(MONO_DTYPES[fmt])
    return data.reshape(component.height, component.width).copy(), fmt
