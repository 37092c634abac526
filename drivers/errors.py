"""Device and configuration failures, each a :class:`~monoguide.solver.errors.MonoguideError`.

``plc_code`` ranges: 4xx devices (camera, laser tracker, later robot and PLC), 5xx configuration.
The ``code`` strings are stable: logs, the journal and the PLC's error register rely on them.
"""

from __future__ import annotations

from monoguide.solver.errors import MonoguideError


class DeviceError(MonoguideError):
    """A device could not do what was asked; the message names the device and what it said."""

    code = "DEVICE_ERROR"
    plc_code = 400


class DeviceNotFound(DeviceError):
    """The device is absent: no such serial port, no camera with that serial, no GenTL producer."""

    code = "DEVICE_NOT_FOUND"
    plc_code = 401


class DeviceTimeout(DeviceError):
    """The device did not answer (or deliver a frame) within the configured time."""

    code = "DEVICE_TIMEOUT"
    plc_code = 402


class DeviceDisconnected(DeviceError):
    """The connection was lost while in use (cable pulled, simulator ended, port closed)."""

    code = "DEVICE_DISCONNECTED"
    plc_code = 403


class DeviceProtocolError(DeviceError):
    """The device answered something the protocol does not allow (garbage, wrong fields, bad command)."""

    code = "DEVICE_PROTOCOL"
    plc_code = 404


class DeviceFault(DeviceError):
    """The device reported a fault of its own (e.g. the tracker's beam is broken); its code is in the message."""

    code = "DEVICE_FAULT"
    plc_code = 405


class DeviceSettingRejected(DeviceError):
    """A setting the cell needs (pixel format, region, ...) is out of the device's range or not supported."""

    code = "DEVICE_SETTING_REJECTED"
    plc_code = 406


class ConfigError(MonoguideError):
    """The cell configuration is invalid; the message names the key, the value and why."""

    code = "CONFIG_INVALID"
    plc_code = 500
