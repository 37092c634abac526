"""``[tracker]``, ``[robot]`` and ``[plc]``: the devices besides the camera, where they are and how long to wait
for them (docs/robot-interface.md, docs/plc-interface.md)."""

from __future__ import annotations

from dataclasses import dataclass

from monoguide.daemon.config._bounds import bounded_integer, bounded_number
from monoguide.daemon.config._reader import ConfigTable
from monoguide.drivers.errors import ConfigError
from monoguide.drivers.plc_registers import WORD_ORDERS as PLC_WORD_ORDERS

TRACKER_BACKENDS = ("serial", "sim")
ROBOT_BACKENDS = ("ur", "kuka", "sim-ur", "sim-kuka")
ROBOT_DEFAULT_PORTS = {"ur": 30004, "kuka": 54600}  # RTDE (fixed); the EKI channel's <PORT>


@dataclass(frozen=True)
class TrackerConfig:
    backend: str
    port: str | None = None
    baud: int = 115200
    timeout_s: float = 2.0


def read_tracker(t: ConfigTable) -> TrackerConfig:
    backend = t.choice("backend", TRACKER_BACKENDS)
    port = t.text("port", None, nonempty=True)
    if backend == "serial" and not port:
        raise ConfigError(f"{t.where}.port: backend 'serial' needs the serial port (e.g. /dev/ttyUSB0)")
    baud = bounded_integer(t, "baud", 115200)
    out = TrackerConfig(backend, port, baud, bounded_number(t, "timeout_s", 2.0))
    t.done()
    return out


@dataclass(frozen=True)
class RobotConfig:
    """``[robot]``: which controller, where, and how long to wait for it (docs/robot-interface.md)."""

    backend: str  # "ur" | "kuka" | "sim-ur" | "sim-kuka"
    host: str = "127.0.0.1"  # the controller; sim-*: where the simulated controller listens
    port: int = 30004
    connect_timeout_s: float = 3.0
    move_timeout_s: float = 30.0  # request measuring pose -> in position
    ack_timeout_s: float = 2.0  # offset written -> acknowledged
    stale_timeout_s: float = 1.0  # no new state from the controller for this long: it has stalled
    rtde_frequency_hz: float = 125.0  # UR: the state recipe's frequency
    pose_tolerance_mm: float = 1.0  # in position, yet this far from the taught flange pose: refused
    pose_tolerance_deg: float = 0.1
    sim_move_time_s: float = 0.5  # sim-*: seconds per move to a measuring pose

    @property
    def make(self) -> str:
        """``"ur"`` or ``"kuka"``: the protocol, whether the controller is real or simulated."""
        return self.backend.removeprefix("sim-")

    @property
    def simulated(self) -> bool:
        return self.backend.startswith("sim-")


def read_robot(t: ConfigTable) -> RobotConfig:
    backend = t.choice("backend", ROBOT_BACKENDS)
    make = backend.removeprefix("sim-")
    port = bounded_integer(t, "port", ROBOT_DEFAULT_PORTS[make])
    if make == "ur" and port != ROBOT_DEFAULT_PORTS["ur"]:
        raise ConfigError(f"{t.where}.port = {port}: a UR controller serves RTDE on 30004 only (ur_rtde cannot "
                          f"use another port)")
    out = RobotConfig(
        backend=backend,
        host=t.host("host", "127.0.0.1"),
        port=port,
        connect_timeout_s=bounded_number(t, "connect_timeout_s", 3.0),
        move_timeout_s=bounded_number(t, "move_timeout_s", 30.0),
        ack_timeout_s=bounded_number(t, "ack_timeout_s", 2.0),
        stale_timeout_s=bounded_number(t, "stale_timeout_s", 1.0),
        rtde_frequency_hz=bounded_number(t, "rtde_frequency_hz", 125.0),
        pose_tolerance_mm=t.number("pose_tolerance_mm", 1.0, positive=True),
        pose_tolerance_deg=t.number("pose_tolerance_deg", 0.1, positive=True),
        sim_move_time_s=bounded_number(t, "sim_move_time_s", 0.5),
    )
    if make == "ur" and out.stale_timeout_s < 2.0 / out.rtde_frequency_hz:
        raise ConfigError(f"{t.where}.stale_timeout_s = {out.stale_timeout_s:g}: must be at least two periods of "
                          f"rtde_frequency_hz = {out.rtde_frequency_hz:g} Hz ({2.0 / out.rtde_frequency_hz:g} s), or "
                          f"every pause between two states counts as a stalled controller")
    t.done()
    return out


@dataclass(frozen=True)
class PlcConfig:
    """``[plc]``: the line's PLC, a Modbus TCP server (docs/plc-interface.md)."""

    host: str
    port: int = 502
    unit: int = 1  # Modbus unit (device) id
    base: int = 0  # holding register of the block's register 0
    word_order: str = "big"  # float32: "big" high word first, "little" low word first
    heartbeat_timeout_s: float = 2.0  # the PLC heartbeat must change at least this often
    timeout_s: float = 1.0  # connect and every request
    ack_timeout_s: float = 10.0  # DONE -> RESULT_ACK with TRIGGER low; longer: FAULT, PLC_ACK_TIMEOUT


def read_plc(t: ConfigTable) -> PlcConfig:
    out = PlcConfig(
        host=t.host("host"),
        port=bounded_integer(t, "port", 502),
        unit=bounded_integer(t, "unit", 1),
        base=bounded_integer(t, "base", 0),
        word_order=t.choice("word_order", PLC_WORD_ORDERS, "big"),
        heartbeat_timeout_s=bounded_number(t, "heartbeat_timeout_s", 2.0),
        timeout_s=bounded_number(t, "timeout_s", 1.0),
        ack_timeout_s=bounded_number(t, "ack_timeout_s", 10.0),
    )
    t.done()
    return out
