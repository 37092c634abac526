"""The service in-process against the PLC a test plays (:mod:`helpers.plc_line`), with the cycle's work stood in
for: :class:`StandIn` measures when released, solves to a seeded offset and "writes" it, so that what is tested is
what the PLC sees, register by register."""

from __future__ import annotations

import asyncio
import contextlib
import threading
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from helpers.cell_configs import plc_cell_config
from helpers.plc_line import WAIT_S, Line, plc_line
from monoguide.daemon.config import load_cell_config
from monoguide.daemon.service import CellDevices, run_service
from monoguide.drivers.plc_registers import Status

OFFSET = (1.25, -2.5, 0.75, 0.1, -0.2, 0.3)  # the stand-in's solved offset: what registers 16-27 must show
QUALITY = (0.05, 0.02, 0.001)


@dataclass
class StandIn:
    """The cycle's work, scripted: ``measure`` waits for ``release`` (or the abort), the rest is instant;
    ``written`` lists the offsets "written to the robot"."""

    release: threading.Event = field(default_factory=threading.Event)
    written: list[tuple[float, ...]] = field(default_factory=list)
    write_started: threading.Event = field(default_factory=threading.Event)
    write_gate: threading.Event | None = None

    def factory(self, _config: Any, _camera: Any, _robot: Any, _images: Any) -> StandIn:
        return self

    def close(self) -> None:
        return None

    def measure(self, job: int, abort: threading.Event, abort_error: Callable[[], Exception],
                holes: bool = True, seen: Any = None) -> Any:
        while not self.release.wait(0.01):
            if abort.is_set():
                raise abort_error()
        if abort.is_set():
            raise abort_error()
        return _Measurement(job)

    def solve(self, measurement: Any) -> Any:
        return _Solution()

    def check(self, measurement: Any, solution: Any) -> None:
        return None

    def write(self, solution: Any, before_send: Callable[[int], None] | None = None) -> int:
        sequence = len(self.written) + 1
        if before_send is not None:
            before_send(sequence)  # the journal's intent, committed before anything goes to the robot
        self.write_started.set()
        if self.write_gate is not None:
            assert self.write_gate.wait(WAIT_S)
        self.written.append(solution.offset)
        return sequence


@dataclass
class _Measurement:
    job: int
    captures: list[Any] = field(default_factory=list)
    record: dict[str, Any] = field(default_factory=lambda: {"kind": "stand-in"})
    timings_s: dict[str, float] = field(default_factory=dict)
    last_frame_at: float = 0.0


@dataclass
class _Solution:
    result: dict[str, Any] = field(default_factory=lambda: {"offset": list(OFFSET)})
    D_b: np.ndarray = field(default_factory=lambda: np.eye(4))
    offset: tuple[float, ...] = OFFSET
    quality: tuple[float, ...] = QUALITY


@contextlib.asynccontextmanager
async def service_on_line(tmp_path: Path, host: str, stand_in: StandIn, devices: CellDevices | None = None,
                                **config: Any) -> AsyncIterator[tuple[Line, asyncio.Task[None], asyncio.Event]]:
    """``run_service`` with ``stand_in`` for the cycle's work, against the PLC at ``host``:5020 (``config``: the
    PLC section's timeouts, :func:`helpers.cell_configs.plc_cell_config`); yields once the PLC reads READY, with
    the service's task and its stop event (SIGTERM's way); stopped at the end."""
    async with plc_line(host) as line:
        cfg = load_cell_config(plc_cell_config(tmp_path, host, line.server.port, **config))
        stop = asyncio.Event()
        service = asyncio.create_task(run_service(cfg, tmp_path / "state", stop=stop,
                                                  devices=devices or CellDevices([]),
                                                  runner_factory=stand_in.factory))
        try:
            await line.wait(lambda s: Status.READY in s, "READY at start")
            yield line, service, stop
        finally:
            stop.set()
            with contextlib.suppress(Exception):
                await asyncio.wait_for(service, WAIT_S)
