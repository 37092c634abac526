"""Every way a cycle ends goes through one place (docs/service.md): journaled, the PLC told, READY honest. In-process
against the PLC the test plays (the real pymodbus server), the cycle's work stood in for (helpers.service_stand_in);
the real devices' failure paths are in test_run_on_sim_cell.py and the fault matrix."""

from __future__ import annotations

import asyncio
import gc
import time
import weakref
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from helpers.cell_configs import plc_cell_config
from helpers.plc_line import WAIT_S, in_own_event_loop, plc_line, record_status_writes
from helpers.service_stand_in import StandIn, service_on_line

from monoguide.daemon.config import load_cell_config
from monoguide.daemon.errors import CycleAborted, CycleUnexpected
from monoguide.daemon.service import CellDevices, Journal, run_service
from monoguide.drivers.plc_registers import CYCLE_COUNTER, Control, Status
from monoguide.solver.errors import HoleNotFound


class Broken(StandIn):
    """The cycle's work with a bug in one stage: it raises what no stage should (a KeyError)."""

    def __init__(self, stage: str) -> None:
        super().__init__()
        self.stage = stage
        self.release.set()

    def measure(self, job: int, abort: Any, abort_error: Any, holes: bool = True, seen: Any = None) -> Any:
        self._maybe("measure")
        return super().measure(job, abort, abort_error)

    def solve(self, measurement: Any) -> Any:
        self._maybe("solve")
        return super().solve(measurement)

    def check(self, measurement: Any, solution: Any) -> None:
        self._maybe("check")

    def write(self, solution: Any, before_send: Any = None) -> int:
        self._maybe("write")
        return super().write(solution, before_send)

    def _maybe(self, stage: str) -> None:
        if stage == self.stage:
            self.stage = "done"  # once: the next cycle works
            raise KeyError(f"no such key in {stage}")


@pytest.mark.parametrize(("stage", "state"), [("measure", "measuring"), ("solve", "solving"), ("check", "checking"),
                                              ("write", "writing")])
@in_own_event_loop
async def test_an_unexpected_exception_in_any_stage_is_journaled_and_reported(tmp_path: Path, stage: str,
                                                                               state: str) -> None:
    """A bug in a stage: DONE + ERROR with CYCLE_UNEXPECTED (605), the journal's row says the stage, the exception's
    type and message; nothing written; the next cycle works (no FAULT to reset)."""
    stand_in = Broken(stage)
    async with service_on_line(tmp_path, "127.0.5.31", stand_in) as (line, _service, _stop):
        await line.control(Control.TRIGGER, job=1, tag=31)
        assert await line.wait(lambda s: Status.DONE in s, "DONE") == Status.DONE | Status.ERROR
        out = (await line.outputs()).result
        assert (out.error_code, out.cycle_counter, out.part_tag, out.offset) == (CycleUnexpected.plc_code, 1, 31,
                                                                                 (0.0,) * 6)
        await line.acknowledge()
        await line.control(Control.TRIGGER, job=1, tag=32)
        assert await line.wait(lambda s: Status.DONE in s, "DONE") == Status.DONE | Status.RESULT_OK
        await line.acknowledge()
    with Journal(tmp_path / "state") as journal:
        failed, good = journal.cycle(1), journal.cycle(2)
    assert (failed.status, failed.error_code, failed.part_tag) == ("error", "CYCLE_UNEXPECTED", 31)
    assert f"unexpected KeyError in state {state}" in (failed.error_message or "")
    assert "no such key in" in (failed.error_message or "")
    assert failed.result is not None
    assert failed.result["failure"]["stage"] == state and failed.result["failure"]["exception"] == "KeyError"
    assert failed.result["failure"]["unexpected"] is True
    assert good.status == "ok" and len(stand_in.written) == 1


@in_own_event_loop
async def test_sigterm_mid_cycle_never_shows_ready_while_stopping(tmp_path: Path) -> None:
    """SIGTERM while BUSY: DONE + ERROR 602, the PLC acknowledges it, and the stopping service shows 0, never READY
    (not even for a poll) before it ends."""
    stand_in = StandIn()  # measures until released: the stop comes while it measures
    async with service_on_line(tmp_path, "127.0.5.32", stand_in) as (line, service, stop):
        await line.control(Control.TRIGGER, job=1, tag=41)
        await line.wait(lambda s: Status.BUSY in s, "BUSY")
        writes = record_status_writes(line.server)
        stop.set()
        assert await line.wait(lambda s: Status.DONE in s, "DONE") == Status.DONE | Status.ERROR
        assert (await line.outputs()).result.error_code == CycleAborted.plc_code
        await line.control(Control.RESULT_ACK)
        await line.wait(lambda s: not s & Status.DONE, "DONE cleared")
        await line.control(0)
        await asyncio.wait_for(service, WAIT_S)
        assert await line.status() == Status(0)
    assert writes, "no status written after the stop"
    assert not [w for w in writes if w & Status.READY], [Status(w) for w in writes]


@in_own_event_loop
async def test_register_13_shows_the_continued_numbering_from_the_first_ready(tmp_path: Path) -> None:
    """An empty journal continues after the number the PLC's register 13 showed (a journal lost with the cell PC):
    register 13 keeps showing it from the first READY, and the next cycle is the one after it."""
    stand_in = StandIn()
    stand_in.release.set()
    async with plc_line("127.0.5.33") as line:
        await line.server.write(CYCLE_COUNTER, [65533])  # left by the service that ran before
        config = load_cell_config(plc_cell_config(tmp_path, "127.0.5.33", line.server.port))
        stop = asyncio.Event()
        service = asyncio.create_task(run_service(config, tmp_path / "state", stop=stop, devices=CellDevices([]),
                                                  runner_factory=stand_in.factory))
        try:
            await line.wait(lambda s: Status.READY in s, "READY")
            assert (await line.outputs()).result.cycle_counter == 65533
            await line.control(Control.TRIGGER, job=1, tag=1)
            assert await line.wait(lambda s: Status.DONE in s, "DONE") == Status.DONE | Status.RESULT_OK
            assert (await line.outputs()).result.cycle_counter == 65534
            await line.acknowledge()
        finally:
            stop.set()
            await asyncio.wait_for(service, WAIT_S)


class HoldsAFrame(StandIn):
    """Measures with a frame-sized array in hand and refuses the hole (what the hole finder's frames hold when it
    raises); ``frame`` a weak reference to that array, to see when it is freed."""

    def __init__(self) -> None:
        super().__init__()
        self.release.set()
        self.frame: Any = None

    def measure(self, job: int, abort: Any, abort_error: Any, holes: bool = True, seen: Any = None) -> Any:
        image = np.zeros((2048, 2448), np.float32)  # a 5 MP frame's grey copy, 20 MB
        self.frame = weakref.ref(image)
        raise HoleNotFound(f"S1, P1: hole expected at (1224.0, 1024.0) r=17.5 px: no hole (frame {image.shape})")


@in_own_event_loop
async def test_a_failed_cycle_keeps_no_frame_once_it_is_reported(tmp_path: Path) -> None:
    """The error of a failed cycle stays known (the state machine's history, the journal) but not its traceback,
    whose frames hold the stage's images: once the cycle is reported the frame is freed at once — by reference
    counting, the garbage collector switched off — as a good cycle's is."""
    stand_in = HoldsAFrame()
    gc.disable()
    try:
        async with service_on_line(tmp_path, "127.0.5.34", stand_in) as (line, _service, _stop):
            await line.control(Control.TRIGGER, job=1, tag=51)
            assert await line.wait(lambda s: Status.DONE in s, "DONE") == Status.DONE | Status.ERROR
            assert (await line.outputs()).result.error_code == HoleNotFound.plc_code
            await line.acknowledge()
            assert stand_in.frame is not None and stand_in.frame() is None, "the failed cycle's frame is still held"
    finally:
        gc.enable()


@in_own_event_loop
async def test_a_cycles_duration_is_not_moved_by_a_step_of_the_clock(tmp_path: Path,
                                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    """The wall clock steps an hour forward while a cycle measures (NTP, a hand set clock): the journal's start
    and end are the wall clock's, its duration the monotonic clock's — the cycle's own 0.3 s."""
    stand_in = StandIn()
    async with service_on_line(tmp_path, "127.0.5.35", stand_in) as (line, _service, _stop):
        await line.control(Control.TRIGGER, job=1, tag=61)
        await line.wait(lambda s: Status.BUSY in s, "BUSY")
        wall = time.time
        monkeypatch.setattr(time, "time", lambda: wall() + 3600.0)  # the step, for every reader of time.time
        await asyncio.sleep(0.3)
        stand_in.release.set()
        assert await line.wait(lambda s: Status.DONE in s, "DONE") == Status.DONE | Status.RESULT_OK
        await line.acknowledge()
    with Journal(tmp_path / "state") as journal:
        row = journal.cycle(1)
    assert row.finished_at - row.started_at > 3600.0  # what the wall clock says
    assert row.duration_s is not None and 0.3 <= row.duration_s < 5.0, row.duration_s
