"""The camera port on a GenICam / GenTL camera through harvesters (GigE Vision, USB3 Vision, ...).

The GenTL producer (``.cti``) comes from the camera vendor; CI uses ``viky.cti`` from the ``genicam``
wheel. Blocking calls: the daemon runs them in worker threads. Every wait has a timeout, every fetched
buffer is re-queued (``with`` block). A camera without a software trigger is free-running: :meth:`grab`
drops the frames already queued and returns the next one.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any

import numpy as np
from genicam.gentl import GenericException, TimeoutException
from harvesters.core import Harvester, ImageAcquirer

from monoguide.drivers.camera import CameraIdentity, CameraSettings, Frame
from monoguide.drivers.errors import (
    DeviceDisconnected,
    DeviceError,
    DeviceNotFound,
    DeviceSettingRejected,
    DeviceTimeout,
)

log = logging.getLogger(__name__)

MONO_DTYPES = {"Mono8": np.uint8, "Mono10": np.uint16, "Mono12": np.uint16, "Mono16": np.uint16}


class GenICamCamera:
    """:class:`~monoguide.drivers.camera.Camera` on harvesters. The device is chosen by ``serial`` or
    ``user_name`` (GenICam ``DeviceUserID``); with neither, the producer must offer exactly one."""

    def __init__(self, cti: str | Path, serial: str | None = None, user_name: str | None = None) -> None:
        self.cti = Path(cti)
        self.serial = serial
        self.user_name = user_name
        self._harvester: Harvester | None = None
        self._acquirer: ImageAcquirer | None = None
        self._identity: CameraIdentity | None = None
        self._software_trigger = False
        self._pixel_format = "Mono8"
        self._frames = 0

    @property
    def identity(self) -> CameraIdentity | None:
        return self._identity

    @property
    def software_trigger(self) -> bool:
        return self._software_trigger

    @property
    def node_map(self) -> Any:
        """The device's GenICam node map, for features the port does not cover (diagnostics, tests)."""
        return self._require_open().remote_device.node_map

    def open(self) -> CameraIdentity:
        if not self.cti.is_file():
            raise DeviceNotFound(f"GenTL producer {self.cti} does not exist")
        self._harvester = Harvester()
        try:
            self._harvester.add_file(str(self.cti), check_existence=True)
            self._harvester.update()
            info = self._choose_device(self._harvester.device_info_list)
            self._acquirer = self._harvester.create({"id_": info.id_})
        except DeviceError:
            self.close()
            raise
        except (GenericException, OSError) as exc:
            self.close()
            raise DeviceNotFound(f"camera via {self.cti.name}: cannot open: {exc}") from exc
        self._identity = CameraIdentity(
            vendor=str(_info(info, "vendor")), model=str(_info(info, "model")),
            serial=str(_info(info, "serial_number")), user_name=_info(info, "user_defined_name") or None,
            version=_info(info, "version"),
        )
        self._frames = 0
        log.info("camera open: %s", self._identity)
        return self._identity

    def configure(self, settings: CameraSettings) -> None:
        acquirer = self._require_open()
        was_running = acquirer.is_acquiring()
        if was_running:
            acquirer.stop()
        nodes = acquirer.remote_device.node_map
        try:
            if settings.pixel_format not in MONO_DTYPES:
                raise DeviceSettingRejected(f"pixel format {settings.pixel_format!r}: monoguide needs one of "
                                            f"{sorted(MONO_DTYPES)}")
            self._set_enum(nodes, "PixelFormat", settings.pixel_format, required=True)
            self._pixel_format = settings.pixel_format
            if settings.region is not None:
                ox, oy, w, h = settings.region
                # shrink first, then move, then grow: each step stays inside the sensor
                self._set_number(nodes, "OffsetX", 0, required=False)
                self._set_number(nodes, "OffsetY", 0, required=False)
                self._set_number(nodes, "Width", w, required=True)
                self._set_number(nodes, "Height", h, required=True)
                self._set_number(nodes, "OffsetX", ox, required=ox != 0)
                self._set_number(nodes, "OffsetY", oy, required=oy != 0)
            if settings.exposure_us is not None and not self._set_number(nodes, "ExposureTime",
                                                                         settings.exposure_us, required=False):
                self._set_number(nodes, "ExposureTimeAbs", settings.exposure_us, required=False)
            if settings.gain_db is not None:
                self._set_number(nodes, "Gain", settings.gain_db, required=False)
            self._software_trigger = self._enable_software_trigger(nodes)
        except GenericException as exc:
            raise DeviceDisconnected(f"camera {self._name()}: configuring failed: {exc}") from exc
        log.info("camera %s: %s, %s", self._name(), settings,
                 "software trigger" if self._software_trigger else "free-running")
        if was_running:
            acquirer.start()

    def grab(self, timeout_s: float) -> Frame:
        acquirer = self._require_open()
        try:
            if not acquirer.is_acquiring():
                acquirer.start()
            if self._software_trigger:
                acquirer.remote_device.node_map.TriggerSoftware.execute()
            else:
                self._drop_queued_frames(acquirer)
            buffer = acquirer.fetch(timeout=timeout_s)
            with buffer:
                image = self._copy_image(buffer)
        except TimeoutException as exc:
            raise DeviceTimeout(f"camera {self._name()}: no frame within {timeout_s:g} s") from exc
        except (GenericException, AttributeError, OSError) as exc:
            # the producer or the device is gone (cable pulled, device reset): the acquirer is unusable
            raise DeviceDisconnected(f"camera {self._name()}: grab failed: {exc!r}") from exc
        self._frames += 1
        return Frame(image, self._frames, time.time(), self._pixel_format)

    def close(self) -> None:
        if self._acquirer is not None:
            try:
                if self._acquirer.is_acquiring():
                    self._acquirer.stop()
                self._acquirer.destroy()
            except (GenericException, AttributeError, OSError) as exc:
                log.warning("camera %s: close: %s", self._name(), exc)
        if self._harvester is not None:
            self._harvester.reset()
        self._acquirer = None
        self._harvester = None

    def __enter__(self) -> GenICamCamera:
        self.open()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    # --- private -------------------------------------------------------------------------------

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

    def _require_open(self) -> ImageAcquirer:
        if self._acquirer is None:
            raise DeviceDisconnected("camera is not open")
        return self._acquirer

    def _name(self) -> str:
        return self._identity.serial if self._identity else str(self.serial or self.user_name or "?")

    def _set_enum(self, nodes: Any, name: str, value: str, required: bool) -> bool:
        if not nodes.has_node(name):
            return self._lacking(name, value, required)
        node = nodes.get_node(name)
        if value not in node.symbolics:
            raise DeviceSettingRejected(f"camera {self._name()}: {name} = {value!r} not supported; "
                                        f"it offers {list(node.symbolics)}")
        node.value = value
        return True

    def _set_number(self, nodes: Any, name: str, value: float, required: bool) -> bool:
        if not nodes.has_node(name):
            return self._lacking(name, value, required)
        node = nodes.get_node(name)
        lo, hi = node.min, node.max
        if not lo <= value <= hi:
            raise DeviceSettingRejected(f"camera {self._name()}: {name} = {value} outside [{lo}, {hi}]")
        node.value = type(node.value)(value)
        return True

    def _lacking(self, name: str, value: object, required: bool) -> bool:
        if required:
            raise DeviceSettingRejected(f"camera {self._name()}: has no {name} feature (wanted {value!r})")
        log.info("camera %s: no %s feature, %r not set", self._name(), name, value)
        return False

    def _enable_software_trigger(self, nodes: Any) -> bool:
        names = ("TriggerSelector", "TriggerMode", "TriggerSource", "TriggerSoftware")
        if not all(nodes.has_node(n) for n in names):
            log.info("camera %s: no software trigger; free-running", self._name())
            return False
        if "FrameStart" in nodes.TriggerSelector.symbolics:
            nodes.TriggerSelector.value = "FrameStart"
        nodes.TriggerMode.value = "On"
        nodes.TriggerSource.value = "Software"
        return True

    def _drop_queued_frames(self, acquirer: ImageAcquirer) -> None:
        # frames exposed before the request; bounded by the number of buffers
        for _ in range(max(1, acquirer.num_buffers) + 1):
            buffer = acquirer.try_fetch(timeout=0.0001)
            if buffer is None:
                return
            buffer.queue()

    def _copy_image(self, buffer: Any) -> np.ndarray:
        component = buffer.payload.components[0]
        fmt = component.data_format
        if fmt not in MONO_DTYPES:
            raise DeviceSettingRejected(f"camera {self._name()}: delivered {fmt}, expected a mono format")
        data = np.asarray(component.data).view(MONO_DTYPES[fmt])
        return data.reshape(component.height, component.width).copy()


def _info(device_info: Any, name: str) -> Any:
    """One field of a GenTL device info; ``None`` where the producer does not provide it."""
    try:
        return getattr(device_info, name)
    except (GenericException, AttributeError):
        return None
