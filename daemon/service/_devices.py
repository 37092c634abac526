"""The cell's camera and robot as the service holds them: opened in worker threads, reopened with backoff.

The drivers block, so every open and close runs in a worker thread (``asyncio.to_thread``); the service's
event loop keeps polling the PLC meanwhile. A device that cannot be opened is retried after a growing
delay (:data:`BACKOFF_S`), and each attempt says so in the log (``camera: cannot connect (...);
reconnecting in 2 s``). A cycle that fails with a lost connection hands its error to :meth:`lost`: the
device it came from is closed and reopened in the background (the others stay open), and the cell is not
READY until it is back. Between cycles the robot is asked every 0.1 s whether it still answers
(:meth:`CellDevices.watch`): a controller lost while the cell waits for a trigger takes READY away at once, not at
the next trigger.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from monoguide.daemon.service._status import DeviceStatus
from monoguide.drivers.errors import DeviceDisconnected, DeviceNotFound, RobotWorkerCrashed
from monoguide.solver.errors import MonoguideError

log = logging.getLogger(__name__)

BACKOFF_S = (0.5, 1.0, 2.0, 4.0, 8.0, 10.0)  # delay before the n-th reconnection attempt; then the last
CONNECTION_LOST = (DeviceDisconnected, DeviceNotFound, RobotWorkerCrashed)
"""Errors of a cycle that mean a device's connection is gone: the devices are reopened."""


@dataclass
class DeviceSlot:
    """One device: how to open it (blocking; returns the opened device), how to close it, and how to ask it between
    cycles whether it still answers (blocking and quick; a :class:`MonoguideError` when not; None: not asked)."""

    name: str
    open: Callable[[], Any]
    close: Callable[[Any], None]
    handle: Any = None
    last_error: MonoguideError | None = None
    attempts: int = 0
    watch: Callable[[Any], None] | None = None

    @property
    def connected(self) -> bool:
        return self.handle is not None


class CellDevices:
    """The cycle's devices (camera, robot) kept connected; :attr:`connected` once all are open."""

    def __init__(self, slots: list[DeviceSlot]) -> None:
        self.slots = {slot.name: slot for slot in slots}
        self._wake = asyncio.Event()
        self._busy = False  # a cycle uses the devices: do not reopen under its feet

    @property
    def connected(self) -> bool:
        return all(slot.connected for slot in self.slots.values())

    def require(self) -> None:
        """Before a cycle uses the devices: :class:`DeviceDisconnected` naming a device that is not connected (lost
        between the trigger and the cycle's start), with why it was lost."""
        for slot in self.slots.values():
            if slot.handle is None:
                why = "" if slot.last_error is None else f": {slot.last_error.code} {slot.last_error.message}"
                error = DeviceDisconnected(f"{slot.name}: not connected{why}; nothing moved")
                error.device = slot.name  # type: ignore[attr-defined]  # as the cycle's own (device_errors)
                raise error

    def handle(self, name: str) -> Any:
        slot = self.slots.get(name)
        return None if slot is None else slot.handle

    def status(self) -> dict[str, DeviceStatus]:
        return {name: DeviceStatus(slot.connected, None if slot.last_error is None else
                                   {"code": slot.last_error.code, "message": slot.last_error.message})
                for name, slot in self.slots.items()}

    def lost(self, error: MonoguideError) -> bool:
        """A cycle met ``error``; when it is a lost connection, reopen the device it came from (``error.device``,
        set where the device was called; every device when it does not say). True if a device is reopened."""
        if not isinstance(error, CONNECTION_LOST):
            return False
        device = getattr(error, "device", None)
        slots = [self.slots[device]] if device in self.slots else [] if device is not None else self.slots.values()
        if not slots:
            return False  # another device's (the PLC's: the service reconnects it itself)
        for slot in slots:
            self._reopen(slot, error)
        return True

    async def watch(self) -> None:
        """Between cycles: ask each connected device that can be asked whether it still answers; one that does not
        is closed and reopened in the background (the cell is not READY until it is back)."""
        for slot in list(self.slots.values()):
            if slot.watch is None or slot.handle is None:
                continue
            handle = slot.handle
            try:
                await asyncio.to_thread(slot.watch, handle)
            except MonoguideError as exc:
                if slot.handle is handle:
                    self._reopen(slot, exc)

    async def keep_connected(self) -> None:
        """Open every closed device, retrying with backoff; runs until cancelled."""
        while True:
            closed = [slot for slot in self.slots.values() if not slot.connected]
            if closed:
                await asyncio.gather(*(self._try_open(slot) for slot in closed))
            if self.connected:
                self._wake.clear()
                await self._wake.wait()
            else:
                delay = min(BACKOFF_S[min(slot.attempts, len(BACKOFF_S)) - 1] for slot in closed
                            if not slot.connected)
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(self._wake.wait(), delay)
                self._wake.clear()

    async def close(self) -> None:
        for slot in self.slots.values():
            handle, slot.handle = slot.handle, None
            if handle is not None:
                try:
                    await asyncio.to_thread(slot.close, handle)
                except Exception as exc:  # closing at exit: say so, carry on with the others
                    log.warning("%s: close failed: %r", slot.name, exc)

    def _reopen(self, slot: DeviceSlot, error: MonoguideError) -> None:
        slot.last_error = error
        if slot.handle is not None:
            handle, slot.handle = slot.handle, None
            log.warning("%s lost (%s %s); reconnecting in %g s", slot.name, error.code, error.message, BACKOFF_S[0])
            with contextlib.suppress(Exception):
                slot.close(handle)  # the driver's close is quick; it must not block the loop for long
        self._wake.set()

    async def _try_open(self, slot: DeviceSlot) -> None:
        try:
            slot.handle = await asyncio.to_thread(slot.open)
        except MonoguideError as exc:
            slot.attempts += 1
            slot.last_error = exc.with_traceback(None)  # its code and message: not the frames (a reference cycle)
            delay = BACKOFF_S[min(slot.attempts, len(BACKOFF_S)) - 1]
            log.warning("%s: cannot connect (%s %s); reconnecting in %g s", slot.name, exc.code, exc.message, delay)
            return
        if slot.attempts or slot.last_error is not None:
            log.info("%s: connected again after %d failed attempt(s)", slot.name, slot.attempts)
        else:
            log.info("%s: connected", slot.name)
        slot.attempts, slot.last_error = 0, None


def cell_devices(config: Any) -> CellDevices:
    """The camera and the robot of ``config`` (built by :mod:`monoguide.daemon.assembly`)."""
    from monoguide.daemon.assembly import build_camera, build_robot, camera_settings

    def open_camera() -> Any:
        camera = build_camera(config)
        camera.open()
        try:
            camera.configure(camera_settings(config))
        except BaseException:
            camera.close()
            raise
        return camera

    def open_robot() -> Any:
        robot = build_robot(config)
        robot.open()
        return robot

    return CellDevices([DeviceSlot("camera", open_camera, lambda camera: camera.close()),
                        DeviceSlot("robot", open_robot, lambda robot: robot.close(),
                                   watch=lambda robot: robot.watch())])
