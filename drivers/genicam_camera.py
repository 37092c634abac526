"""The camera port on a GenICam / GenTL camera through harvesters (GigE Vision, USB3 Vision, ...).

The GenTL producer (``.cti``) comes from the camera vendor; CI uses ``viky.cti`` from the ``genicam``
wheel. Blocking calls: the daemon runs them in worker threads, and one lock per camera keeps two threads
from interleaving their calls. Every wait has a timeout, every fetched buffer is re-queued. Every grab
returns a frame exposed after the request (:mod:`monoguide.drivers.genicam_frames`: queued frames
flushed, late trigger answers and frames in flight dropped). Settings are checked against the node limits
and every library exception is translated at this boundary (:mod:`monoguide.drivers.genicam_nodes`).
"""

from __future__ import annotations

import logging
import math
import threading
from pathlib import Path
from typing import Any

from harvesters.core import Harvester, ImageAcquirer

from monoguide.drivers.camera import CameraIdentity, CameraSettings, Frame
from monoguide.drivers.errors import (
    DeviceDisconnected,
    DeviceError,
    DeviceNotFound,
    DeviceRequestInvalid,
    DeviceSettingRejected,
)
from monoguide.drivers.genicam_frames import MONO_DTYPES, FreshFrames
from monoguide.drivers.genicam_nodes import device_errors, enable_software_trigger, set_enum, set_number

log = logging.getLogger(__name__)

__all__ = ["MONO_DTYPES", "GenICamCamera"]


class GenICamCamera:
    """:class:`~monoguide.drivers.camera.Camera` on harvesters. The device is chosen by ``serial`` or
    ``user_name`` (GenICam ``DeviceUserID``); with neither, the producer must offer exactly one.
    ``in_flight_frames``: how many frames a free-running camera may have in flight at a request (dropped)."""

    def __init__(self, cti: str | Path, serial: str | None = None, user_name: str | None = None,
                 in_flight_frames: int = 2) -> None:
        self.cti = Path(cti)
        self.serial = serial
        self.user_name = user_name
        self.in_flight_frames = in_flight_frames
        self._lock = threading.RLock()
        self._harvester: Harvester | None = None
        self._acquirer: ImageAcquirer | None = None
        self._identity: CameraIdentity | None = None
        self._frames_source: FreshFrames | None = None
        self._pixel_format = "Mono8"
        self._frames = 0

    @property
    def identity(self) -> CameraIdentity | None:
        return self._identity

    @property
    def software_trigger(self) -> bool:
        return self._frames_source is not None and self._frames_source.triggered

    @property
    def node_map(self) -> Any:
        """The device's GenICam node map, for features the port does not cover (diagnostics, tests). Calls
        on it are not translated: use the port's methods in the cycle."""
        return self._require_open().remote_device.node_map

    def open(self) -> CameraIdentity:
        with self._lock:
            if self._acquirer is not None:
                return self._identity  # type: ignore[return-value]
            self._acquirer, self._identity = self._connect()
            self._frames_source = FreshFrames(self._acquirer, f"camera {self._name()}",
                                              in_flight=self.in_flight_frames)
            self._frames = 0
            log.info("camera open: %s", self._identity)
            return self._identity

    def configure(self, settings: CameraSettings) -> None:
        with self._lock:
            acquirer = self._require_open()
            name = f"camera {self._name()}"
            with device_errors(name, "stopping the acquisition to configure"):
                was_running = acquirer.is_acquiring()
                if was_running:
                    acquirer.stop()
                nodes = acquirer.remote_device.node_map
            if settings.pixel_format not in MONO_DTYPES:
                raise DeviceSettingRejected(f"{name}: pixel format {settings.pixel_format!r}: monoguide needs one "
                                            f"of {sorted(MONO_DTYPES)}")
            set_enum(nodes, name, "PixelFormat", settings.pixel_format, required=True)
            self._pixel_format = settings.pixel_format
            if settings.region is not None:
                ox, oy, w, h = settings.region
                # shrink first, then move, then grow: each step stays inside the sensor
                set_number(nodes, name, "OffsetX", 0, required=False)
                set_number(nodes, name, "OffsetY", 0, required=False)
                set_number(nodes, name, "Width", w, required=True)
                set_number(nodes, name, "Height", h, required=True)
                set_number(nodes, name, "OffsetX", ox, required=ox != 0)
                set_number(nodes, name, "OffsetY", oy, required=oy != 0)
            if settings.exposure_us is not None and not set_number(nodes, name, "ExposureTime",
                                                                   settings.exposure_us, required=False):
                set_number(nodes, name, "ExposureTimeAbs", settings.exposure_us, required=False)
            if settings.gain_db is not None:
                set_number(nodes, name, "Gain", settings.gain_db, required=False)
            trigger = self._software_trigger(nodes) if enable_software_trigger(nodes, name) else None
            self._frames_source = FreshFrames(acquirer, name, trigger, in_flight=self.in_flight_frames)
            log.info("%s: %s, %s", name, settings, "software trigger" if trigger else "free-running")
            if was_running:
                with device_errors(name, "restarting the acquisition"):
                    acquirer.start()

    def grab(self, timeout_s: float) -> Frame:
        if isinstance(timeout_s, bool) or not isinstance(timeout_s, int | float) or not timeout_s > 0 \
                or not math.isfinite(timeout_s):
            raise DeviceRequestInvalid(f"camera {self._name()}: grab timeout {timeout_s!r} s must be a finite "
                                       f"number > 0")
        with self._lock:
            self._require_open()
            assert self._frames_source is not None
            with device_errors(f"camera {self._name()}", f"grab (timeout {timeout_s:g} s)"):
                fresh = self._frames_source.grab(timeout_s)
            self._frames += 1
            return Frame(fresh.image, self._frames, fresh.received_time_s, fresh.pixel_format, fresh.frame_id,
                         fresh.requested_time_s)

    def close(self) -> None:
        with self._lock:
            if self._acquirer is not None:
                try:
                    with device_errors(f"camera {self._name()}", "close"):
                        if self._acquirer.is_acquiring():
                            self._acquirer.stop()
                        self._acquirer.destroy()
                except DeviceError as exc:
                    log.warning("%s", exc)
            if self._harvester is not None:
                try:
                    with device_errors(f"camera {self._name()}", "releasing the producer"):
                        self._harvester.reset()
                except DeviceError as exc:
                    log.warning("%s", exc)
            self._acquirer = None
            self._harvester = None
            self._frames_source = None

    def __enter__(self) -> GenICamCamera:
        self.open()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    # --- private -------------------------------------------------------------------------------

    def _connect(self) -> tuple[ImageAcquirer, CameraIdentity]:
        """Load the producer, choose the device, create its acquirer (the only place harvesters is built)."""
        if not self.cti.is_file():
            raise DeviceNotFound(f"GenTL producer {self.cti} does not exist")
        try:
            with device_errors(f"camera via {self.cti.name}", "open"):
                self._harvester = Harvester()
                try:
                    self._harvester.add_file(str(self.cti), check_existence=True)
                    self._harvester.update()
                except OSError as exc:
                    raise DeviceNotFound(f"camera via {self.cti.name}: cannot load the producer: {exc}") from exc
                info = self._choose_device(self._harvester.device_info_list)
                acquirer = self._harvester.create({"id_": info.id_})
        except DeviceDisconnected as exc:  # the producer could not reach the device: it is not there
            self.close()
            raise DeviceNotFound(str(exc)) from exc
        except BaseException:
            self.close()
            raise
        identity = CameraIdentity(
            vendor=str(_info(info, "vendor")), model=str(_info(info, "model")),
            serial=str(_info(info, "serial_number")), user_name=_info(info, "user_defined_name") or None,
            version=_info(info, "version"),
        )
        return acquirer, identity

    def _choose_device(self, devices: list[Any]) -> Any:
        if not devices:
            raise DeviceNotFound(f"GenTL producer {self.cti} offers no camera (not a GenTL producer, or no "
                                 f"camera connected)")
        found = [f"serial {_info(d, 'serial_number')!r} / user name {_info(d, 'user_defined_name')!r}"
                 for d in devices]
        if self.serial is not None:
            chosen = [d for d in devices if str(_info(d, "serial_number")) == self.serial]
        elif self.user_name is not None:
            chosen = [d for d in devices if _info(d, "user_defined_name") == self.user_name]
        else:
            chosen = list(devices)
        if len(chosen) != 1:
            wanted = f"serial {self.serial!r}" if self.serial is not None else f"user name {self.user_name!r}"
            if self.serial is None and self.user_name is None:
                wanted = "exactly one camera (no serial or user_name configured)"
            raise DeviceNotFound(f"camera via {self.cti.name}: {len(chosen)} match {wanted}; found: {found}")
        return chosen[0]

    def _software_trigger(self, nodes: Any) -> Any:
        def fire() -> None:
            nodes.TriggerSoftware.execute()  # translated by grab's device_errors

        return fire

    def _require_open(self) -> ImageAcquirer:
        if self._acquirer is None:
            raise DeviceDisconnected("camera is not open")
        return self._acquirer

    def _name(self) -> str:
        return self._identity.serial if self._identity else str(self.serial or self.user_name or "?")


def _info(device_info: Any, name: str) -> Any:
    """One field of a GenTL device info; ``None`` where the producer does not provide it."""
    try:
        return getattr(device_info, name)
    except Exception:  # genicam.gentl errors or a missing attribute: the producer does not provide it
        return None
