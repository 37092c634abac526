"""Device and configuration failures, each a :class:`~monoguide.solver.errors.MonoguideError`.

``plc_code`` ranges: 4xx devices (camera, laser tracker, robot 420-449, PLC 450-469), 5xx configuration.
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


class DeviceBusy(DeviceError):
    """Another client holds the device (a serial port locked by another process, a state file claimed by a
    running simulated cell); the message names the port or path."""

    code = "DEVICE_BUSY"
    plc_code = 407


class DeviceRequestInvalid(DeviceError):
    """A request the device's protocol cannot carry (a nest name with a space, a non-ASCII word, an
    over-long line); the message names the value. Nothing was sent."""

    code = "DEVICE_REQUEST_INVALID"
    plc_code = 408


# --- robot (420-449) ---------------------------------------------------------------------------


class RobotError(DeviceError):
    """The robot could not do what the cycle asked; the message names the robot and what it reported."""

    code = "ROBOT_ERROR"
    plc_code = 420


class RobotNotReady(RobotError):
    """The robot is not ready for the cycle: no program running, not powered, not in remote/automatic."""

    code = "ROBOT_NOT_READY"
    plc_code = 421


class RobotProtectiveStop(RobotError):
    """The robot is in a protective or emergency stop (safety mode not normal)."""

    code = "ROBOT_PROTECTIVE_STOP"
    plc_code = 422


class RobotPositionTimeout(RobotError):
    """The robot did not report the requested measuring pose in position within the configured time."""

    code = "ROBOT_POSITION_TIMEOUT"
    plc_code = 423


class RobotAckTimeout(RobotError):
    """The robot did not acknowledge the offset's sequence number within the configured time."""

    code = "ROBOT_ACK_TIMEOUT"
    plc_code = 424


class RobotWorkerCrashed(RobotError):
    """The process holding the robot's client library ended unexpectedly; it is restarted on the next call."""

    code = "ROBOT_WORKER_CRASHED"
    plc_code = 425


class RobotCommandRejected(RobotError):
    """The robot program refused a request (unknown measuring pose, offset out of its limits); its status
    code is in the message."""

    code = "ROBOT_COMMAND_REJECTED"
    plc_code = 426


class RobotPoseMismatch(RobotError):
    """The robot reports in position but its actual flange pose is farther from the taught measuring pose than
    the configured tolerance."""

    code = "ROBOT_POSE_MISMATCH"
    plc_code = 427


class RobotMessageInvalid(RobotError):
    """A robot message broke the protocol (malformed, truncated, oversized or hostile XML, a bad RTDE
    package); the message quotes what arrived. Nothing in it was used."""

    code = "ROBOT_MESSAGE_INVALID"
    plc_code = 428


class RobotOffsetUnconfirmed(RobotError):
    """The offset was sent but its acknowledgement was not seen (controller lost, no answer in time, the service
    ended): the robot may hold this cycle's offset. Do not grasp; FAULT stays latched until monoguide has
    settled it against the offset the robot reports it holds and cleared it (docs/plc-interface.md)."""

    code = "ROBOT_OFFSET_UNCONFIRMED"
    plc_code = 429


class RobotSyncTimeout(RobotError):
    """The robot program did not answer sequence 0 after a connect in time (acknowledged 0 with status 2; an
    older template answers status 0, or the program is stuck in a move): nothing was sent. Load the robot programs
    of this version (docs/robot-interface.md)."""

    code = "ROBOT_SYNC_TIMEOUT"
    plc_code = 430


# --- PLC (450-469) ----------------------------------------------------------------------------


class PlcError(DeviceError):
    """The line's PLC broke the handshake of ``docs/plc-interface.md``; the message names the register."""

    code = "PLC_ERROR"
    plc_code = 450


class PlcValueInvalid(PlcError):
    """A register the PLC writes holds a value the contract does not allow (an undefined control bit, job
    number 0); the message names the register and the value. Nothing in it was used."""

    code = "PLC_VALUE_INVALID"
    plc_code = 451


class PlcHeartbeatLost(PlcError):
    """The PLC's heartbeat (register 2) did not change within ``[plc] heartbeat_timeout_s``: FAULT."""

    code = "PLC_HEARTBEAT_LOST"
    plc_code = 452


class PlcTriggerDropped(PlcError):
    """The PLC dropped TRIGGER while the cycle was busy: the cycle was aborted, nothing written to the robot."""

    code = "PLC_TRIGGER_DROPPED"
    plc_code = 453


class PlcAckTimeout(PlcError):
    """The PLC did not set RESULT_ACK and drop TRIGGER within the configured time after DONE."""

    code = "PLC_ACK_TIMEOUT"
    plc_code = 454


class PlcUnknownJob(PlcError):
    """The job number (register 1) selects no part entry of the config; the message names it."""

    code = "PLC_UNKNOWN_JOB"
    plc_code = 455


class ConfigError(MonoguideError):
    """The cell configuration is invalid; the message names the key, the value and why."""

    code = "CONFIG_INVALID"
    plc_code = 500
