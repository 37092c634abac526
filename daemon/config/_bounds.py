"""The documented range of every duration and count of the cell config (docs/cell-config.md), and the two
getters a section reader reads such a key with.

A key read with :func:`bounded_number` or :func:`bounded_integer` must have its row in :data:`BOUNDS`
(``"section.key"``); ``tests/daemon/test_config_bounds.py`` fails for a duration or a count read without one,
and for a range the doc does not state.
"""

from __future__ import annotations

from typing import Any

from monoguide.daemon.config._reader import Bounds, ConfigTable
from monoguide.drivers.plc_registers import BLOCK_SIZE as PLC_BLOCK_SIZE

# "section.key" -> Bounds; the loader refuses a value outside it (NaN and infinities included), naming the key,
# the value and the range.
BOUNDS: dict[str, Bounds] = {
    "camera.grab_timeout_s": Bounds(0.05, 60.0, "s"),
    "camera.exposure_us": Bounds(1.0, 10_000_000.0, "us"),
    "camera.intrinsics.width": Bounds(1, 65535, "px"),
    "camera.intrinsics.height": Bounds(1, 65535, "px"),
    "tracker.baud": Bounds(300, 4_000_000),
    "tracker.timeout_s": Bounds(0.05, 600.0, "s"),
    "robot.port": Bounds(1, 65535),
    "robot.connect_timeout_s": Bounds(0.05, 60.0, "s"),
    "robot.move_timeout_s": Bounds(0.05, 600.0, "s"),
    # a written offset's acknowledgement is waited out on SIGTERM: well inside systemd's TimeoutStopSec=30s
    "robot.ack_timeout_s": Bounds(0.05, 10.0, "s"),
    "robot.stale_timeout_s": Bounds(0.05, 10.0, "s"),
    "robot.rtde_frequency_hz": Bounds(1.0, 500.0, "Hz"),  # a UR controller sends at most 500 Hz
    "robot.sim_move_time_s": Bounds(0.0, 60.0, "s"),
    "plc.port": Bounds(1, 65535),
    "plc.unit": Bounds(1, 255),
    "plc.base": Bounds(0, 65536 - PLC_BLOCK_SIZE),  # the block's 34 registers must fit
    "plc.heartbeat_timeout_s": Bounds(0.1, 60.0, "s"),  # the service reads the heartbeat every 20 ms
    "plc.timeout_s": Bounds(0.05, 60.0, "s"),
    "plc.ack_timeout_s": Bounds(0.05, 600.0, "s"),
    "service.images_max_mb": Bounds(1.0, 10_000_000.0, "MB"),
    "service.images_max_age_days": Bounds(0.01, 3650.0, "days"),
    "sim.exposure_us_nominal": Bounds(1.0, 10_000_000.0, "us"),
    "checks.check_visits": Bounds(1, 50),  # each visit: every measuring pose once
    "parts.job": Bounds(1, 65534),  # PLC register 1 (a uint16; 0 is no job, 65535 the check job)
    "calibration_target.marks_cols": Bounds(2, 1000),
    "calibration_target.marks_rows": Bounds(2, 1000),
}


def bounded_number(t: ConfigTable, key: str, *default: Any) -> Any:
    """A number within its documented range, :data:`BOUNDS` ``[section.key]``."""
    return t.number(key, *default, bounds=BOUNDS[f"{t.name}.{key}"])


def bounded_integer(t: ConfigTable, key: str, *default: Any) -> Any:
    """An integer within its documented range, :data:`BOUNDS` ``[section.key]``."""
    return t.integer(key, *default, bounds=BOUNDS[f"{t.name}.{key}"])
