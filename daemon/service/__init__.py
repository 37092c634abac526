"""The service, ``monoguide run``: the loop, the PLC link, the cycle task, the devices kept connected, the
journal, the state directory and its status file, sd_notify (docs/service.md).

The readers' parts (journal, status file, state directory) are light; the loop (``run_service``) is loaded when
it is first asked for, so ``monoguide status`` and ``journal`` start without the cycle's libraries.
"""

from __future__ import annotations

from typing import Any

from monoguide.daemon.service._journal import JOURNAL_FILE, CycleEntry, CycleQuery, Journal, JournalRow, OffsetIntent
from monoguide.daemon.service._journal_query import MAX_PAGE
from monoguide.daemon.service._state_dir import (
    CLEAR_REQUEST,
    DEFAULT_STATE_DIR,
    HEALTH_FILE,
    STATE_DIR_HELP,
    ServiceLock,
    create_state_dir,
    existing_state_dir,
    state_dir,
)
from monoguide.daemon.service._status import (
    STATUS_FILE,
    DeviceStatus,
    ServiceStatus,
    liveness,
    read_status,
    write_status,
)

__all__ = [
    "CLEAR_REQUEST", "DEFAULT_STATE_DIR", "HEALTH_FILE", "JOURNAL_FILE", "MAX_PAGE", "STATE_DIR_HELP", "STATUS_FILE",
    "CellDevices", "CycleEntry",
    "CycleQuery", "DeviceSlot", "DeviceStatus", "Journal", "JournalRow", "Notifier", "OffsetIntent", "OffsetLedger",
    "ServiceLock", "ServiceStatus", "create_state_dir", "existing_state_dir", "liveness", "read_status", "run_service",
    "state_dir", "watchdog_interval_s", "write_status",
]


def __getattr__(name: str) -> Any:
    """The loop's parts, loaded when first asked for (they bring the drivers and numpy)."""
    if name == "run_service":
        from monoguide.daemon.service._loop import run_service

        return run_service
    if name in ("CellDevices", "DeviceSlot"):
        from monoguide.daemon.service import _devices

        return getattr(_devices, name)
    if name in ("Notifier", "watchdog_interval_s"):
        from monoguide.daemon.service import _sd_notify

        return getattr(_sd_notify, name)
    if name == "OffsetLedger":
        from monoguide.daemon.service._offsets import OffsetLedger

        return OffsetLedger
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
