"""Nothing reaches the robot unrecorded, and the cell never stops by itself — what the PLC sees, register by
register, over the real pymodbus server and client (in-process, as test_handshake.py): the cycle
counter across 65,535 -> 0, the offset's intent before the send (a full disk: nothing sent), a controller lost
mid-write (settled at once, or FAULT 429 until it is), the kill -9 window, the journal deleted under the
service, the abort's code on the next connection, a TRIGGER low shorter than a poll, the status word kept.

The robot here is a scripted stand-in for the port's settling calls (``held_offset``, ``clear_offset``): what
it "holds" is the test's ground truth. The same cases over the real robot transports with the simulated
controllers are in tests/daemon/service/test_run_on_sim_cell.py."""

from __future__ import annotations

import asyncio
import contextlib
import signal
import sqlite3
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
from helpers.cell_configs import plc_cell_config
from helpers.disks import fill, small_file_system
from helpers.plc_line import WAIT_S, Line, in_own_event_loop, plc_line
from helpers.service_stand_in import OFFSET, StandIn, service_on_line

from monoguide.daemon.config import load_cell_config
from monoguide.daemon.errors import CycleUnexpected, JournalError, JournalReplaced
from monoguide.daemon.service import CellDevices, DeviceSlot, Journal, run_service
from monoguide.drivers.errors import (
    DeviceDisconnected,
    DeviceNotFound,
    PlcValueInvalid,
    RobotAckTimeout,
    RobotCommandRejected,
    RobotOffsetUnconfirmed,
)
from monoguide.drivers.plc_registers import CONTROL, STATUS, Control, Status
from monoguide.drivers.robot import HeldOffset

ZERO = (0.0,) * 6


@dataclass
class HeldByRobot:
    """The robot's side of settling, scripted: which request's offset it holds (the truth), whether it answers."""

    sequence: int = 0
    valid: bool = False
    reachable: bool = True
    clears: list[int] = field(default_factory=list)
    asked: int = 0

    def held_offset(self, timeout_s: float | None = None) -> HeldOffset:
        self.asked += 1
        if not self.reachable:
            raise DeviceNotFound("robot 127.0.0.1:30004: cannot connect: connection refused")
        return HeldOffset(self.sequence, self.valid)

    def clear_offset(self, timeout_s: float | None = None) -> int:
        if not self.reachable:
            raise DeviceNotFound("robot 127.0.0.1:30004: cannot connect: connection refused")
        self.sequence, self.valid = 0, False
        self.clears.append(len(self.clears) + 1000)
        return self.clears[-1]

    def close(self) -> None:
        return None


@dataclass
class FailingWrite(StandIn):
    """The stand-in whose offset write fails after the send with ``error``; ``robot_takes`` says whether the
    robot took it meanwhile (the scripted robot then holds that request)."""

    error: Exception | None = None
    robot: HeldByRobot | None = None
    robot_takes: bool = False

    def write(self, solution: Any, before_send: Any = None) -> int:
        sequence = len(self.written) + 1
        if before_send is not None:
            before_send(sequence)
        if self.error is None:
            self.written.append(solution.offset)
            return sequence
        if self.robot_takes and self.robot is not None:
            self.robot.sequence, self.robot.valid = sequence, True
            self.written.append(solution.offset)
        raise self.error


@contextlib.asynccontextmanager
async def _service(tmp_path: Path, line: Line, stand_in: StandIn, devices: CellDevices | None = None) -> Any:
    """``run_service`` on ``line``'s PLC, without waiting for READY; stopped (SIGTERM's way) at the end."""
    cfg = load_cell_config(plc_cell_config(tmp_path, line.server.host, line.server.port))
    stop = asyncio.Event()
    task = asyncio.create_task(run_service(cfg, tmp_path / "state", stop=stop, devices=devices or CellDevices([]),
                                           runner_factory=stand_in.factory))
    try:
        yield task
    finally:
        stop.set()
        await asyncio.wait_for(task, WAIT_S)


def _devices(robot: HeldByRobot) -> CellDevices:
    return CellDevices([DeviceSlot("robot", lambda: robot, lambda r: None)])


async def _trigger(line: Line, tag: int) -> None:
    await line.wait(lambda s: Status.READY in s, "READY")
    await line.control(Control.TRIGGER, job=1, tag=tag)
    await line.wait(lambda s: Status.BUSY in s or Status.DONE in s or Status.FAULT in s, "BUSY")


async def _fault_reset(line: Line) -> None:
    await line.control(Control.FAULT_RESET)
    await asyncio.sleep(0.1)
    await line.control(0)


def _intents(state_dir: Path) -> list[Any]:
    """The offset intents of the journal's cycles, oldest first (cycles without one left out)."""
    with Journal(state_dir) as journal:
        found = [journal.intent(row.number) for row in journal.last_cycles(100)[::-1]]
    return [intent for intent in found if intent is not None]


def _set_counter(state_dir: Path, counter: int) -> None:
    """A journal whose last cycle is ``counter``: what a cell that has run for months holds."""
    with Journal(state_dir) as journal:
        journal.commit_cycle(_failed_entry())
    db = sqlite3.connect(state_dir / "journal.sqlite3")
    with db:
        db.execute("UPDATE cycle SET number = ? WHERE number = 1", (counter,))
        db.execute("UPDATE sqlite_sequence SET seq = ? WHERE name = 'cycle'", (counter,))
    db.close()


def _failed_entry() -> Any:
    from monoguide.daemon.service import CycleEntry

    return CycleEntry(started_at=1.0, finished_at=2.0, job=1, part_tag=1, error=DeviceDisconnected("camera gone"))


# --- the cycle counter wraps where the contract says ----------------------------------------------------------


@pytest.mark.parametrize(("last", "host"), [(65_533, "127.0.46.1"), (300_000, "127.0.46.2")])
@in_own_event_loop
async def test_the_cycle_counter_wraps_65535_to_0_and_the_journal_counts_on(tmp_path: Path, last: int,
                                                                             host: str) -> None:
    _set_counter(tmp_path / "state", last)
    stand_in = StandIn()
    stand_in.release.set()
    shown = []
    async with service_on_line(tmp_path, host, stand_in) as (line, _service, _stop):
        assert (await line.outputs()).result.cycle_counter == last % 65536  # at start: the journal's last cycle
        for tag in range(4):
            await _trigger(line, tag)
            assert await line.wait(lambda s: Status.DONE in s, "DONE") == Status.DONE | Status.RESULT_OK
            shown.append((await line.outputs()).result.cycle_counter)
            await line.acknowledge()
    assert shown == [(last + n) % 65536 for n in (1, 2, 3, 4)]
    if last == 65_533:
        assert shown == [65_534, 65_535, 0, 1]
    with Journal(tmp_path / "state") as journal:
        assert [row.number for row in journal.last_cycles(4)][::-1] == [last + n for n in (1, 2, 3, 4)]
    assert [i.outcome for i in _intents(tmp_path / "state")][-4:] == ["acknowledged"] * 4
    assert len(stand_in.written) == 4


# --- an intent before every offset -----------------------------------------------------------------------------


@in_own_event_loop
async def test_every_written_offset_has_its_intent_and_outcome(tmp_path: Path) -> None:
    stand_in = StandIn()
    stand_in.release.set()
    async with service_on_line(tmp_path, "127.0.46.3", stand_in) as (line, _service, _stop):
        for tag in (1, 2):
            await _trigger(line, tag)
            await line.wait(lambda s: Status.DONE in s, "DONE")
            await line.acknowledge()
    intents = _intents(tmp_path / "state")
    assert [(i.cycle, i.sequence, i.outcome, i.cleared) for i in intents] == [
        (1, 1, "acknowledged", False), (2, 2, "acknowledged", False)]
    assert all(i.registers == pytest.approx(OFFSET) for i in intents)
    assert all(i.settled_at >= i.intended_at for i in intents)


@in_own_event_loop
async def test_a_full_disk_means_nothing_is_sent_and_the_plc_is_told(tmp_path: Path) -> None:
    with small_file_system(tmp_path / "disk") as disk:
        robot = HeldByRobot()
        stand_in = FailingWrite(robot=robot)
        stand_in.release.set()
        async with service_on_line(disk, "127.0.46.4", stand_in, devices=_devices(robot)) as (line, _service, _stop):
            await _trigger(line, 1)
            await line.wait(lambda s: Status.DONE in s, "DONE")
            await line.acknowledge()  # cycle 1, before the disk fills: good
            filler = fill(disk)
            await _trigger(line, 2)  # nothing reaches the robot; the cycle's row cannot be committed either
            status = await line.wait(lambda s: Status.FAULT in s, "FAULT")
            assert not status & (Status.DONE | Status.RESULT_OK)
            out = await line.outputs()
            assert (out.result.error_code, out.result.cycle_counter) == (JournalError.plc_code, 1)
            await _fault_reset(line)  # ignored: the journal still cannot take the cycle that ended
            await asyncio.sleep(0.3)
            assert Status.FAULT in await line.status()
            assert stand_in.written == [OFFSET]  # only cycle 1's offset ever reached the robot
            filler.unlink()  # room again: FAULT_RESET journals cycle 2, and the line runs on
            await _fault_reset(line)
            await _trigger(line, 4)
            assert await line.wait(lambda s: Status.DONE in s, "DONE") == Status.DONE | Status.RESULT_OK
            assert (await line.outputs()).result.cycle_counter == 3
            await line.acknowledge()
        assert [(i.cycle, i.outcome) for i in _intents(disk / "state")] == [(1, "acknowledged"), (3, "acknowledged")]
        with Journal(disk / "state") as journal:
            failed = journal.cycle(2)
        assert (failed.error_code, failed.part_tag) == ("JOURNAL_ERROR", 2)  # journaled once the disk had room


# --- a write that fails after the send is settled ----------------------------------------------------------------


@pytest.mark.parametrize(("robot_takes", "error", "host"), [
    (False, DeviceDisconnected("robot: the controller closed the connection"), "127.0.46.5"),
    (True, DeviceDisconnected("robot: the controller closed the connection"), "127.0.46.6"),
    (True, RobotAckTimeout("robot: not offset acknowledged within 2 s"), "127.0.46.7"),
], ids=["lost-before-taking", "lost-after-taking", "ack-timeout-taken-late"])
@in_own_event_loop
async def test_a_failed_write_to_a_robot_that_answers_is_settled_at_once(tmp_path: Path, robot_takes: bool,
                                                                         error: Exception, host: str) -> None:
    robot = HeldByRobot(sequence=0)
    stand_in = FailingWrite(error=error, robot=robot, robot_takes=robot_takes)
    stand_in.release.set()
    async with service_on_line(tmp_path, host, stand_in, devices=_devices(robot)) as (line, _service, _stop):
        await _trigger(line, 7)
        status = await line.wait(lambda s: Status.DONE in s, "DONE")
        assert status == Status.DONE | Status.ERROR  # ERROR: the robot holds nothing from this cycle
        out = await line.outputs()
        assert (out.result.error_code, out.result.cycle_counter, out.result.offset) == (error.plc_code, 1, ZERO)
        await line.acknowledge()
    assert (robot.sequence, robot.valid, len(robot.clears)) == (0, False, 1)  # cleared, whatever it held
    (intent,) = _intents(tmp_path / "state")
    assert (intent.outcome, intent.cleared) == ("held" if robot_takes else "not_held", True)
    with Journal(tmp_path / "state") as journal:
        row = journal.cycle(1)
    assert row.error_code == type(error).code and "settled" in row.error_message


@pytest.mark.parametrize(("reachable", "host"), [(True, "127.0.46.30"), (False, "127.0.46.31")],
                         ids=["robot-answers", "robot-cannot-say"])
@in_own_event_loop
async def test_an_unexpected_exception_after_the_send_is_settled_as_any_failed_write(tmp_path: Path, reachable: bool,
                                                                                     host: str) -> None:
    """A bug raising in the write after the offset went out: the robot may hold it, so it is settled as after a lost
    connection — ERROR CYCLE_UNEXPECTED once the robot says (and cleared it), FAULT 429 while it cannot."""
    robot = HeldByRobot(sequence=0, reachable=reachable)
    stand_in = FailingWrite(error=KeyError("a bug after the send"), robot=robot, robot_takes=True)
    stand_in.release.set()
    async with service_on_line(tmp_path, host, stand_in, devices=_devices(robot)) as (line, _service, _stop):
        await _trigger(line, 8)
        status = await line.wait(lambda s: bool(s & (Status.DONE | Status.FAULT)), "DONE or FAULT")
        out = (await line.outputs()).result
        if reachable:
            assert status == Status.DONE | Status.ERROR
            assert (out.error_code, out.offset) == (CycleUnexpected.plc_code, ZERO)
            await line.acknowledge()
        else:
            assert Status.FAULT in status and out.error_code == RobotOffsetUnconfirmed.plc_code
    (intent,) = _intents(tmp_path / "state")
    with Journal(tmp_path / "state") as journal:
        row = journal.cycle(1)
    if reachable:
        assert (robot.sequence, robot.valid) == (0, False)
        assert (intent.outcome, intent.cleared) == ("held", True)
        assert row.error_code == "CYCLE_UNEXPECTED" and "settled" in (row.error_message or "")
        assert row.result is not None and row.result["failure"]["exception"] == "KeyError"
    else:
        assert (robot.sequence, robot.valid) == (1, True) and intent.outcome is None  # still to settle
        assert row.error_code == "ROBOT_OFFSET_UNCONFIRMED"


@in_own_event_loop
async def test_an_offset_refused_by_the_program_is_an_error_and_nothing_held(tmp_path: Path) -> None:
    robot = HeldByRobot()
    stand_in = FailingWrite(error=RobotCommandRejected("robot: program refused offset 1: status -3"), robot=robot)
    stand_in.release.set()
    async with service_on_line(tmp_path, "127.0.46.8", stand_in, devices=_devices(robot)) as (line, _service, _stop):
        await _trigger(line, 7)
        assert await line.wait(lambda s: Status.DONE in s, "DONE") == Status.DONE | Status.ERROR
        assert (await line.outputs()).result.error_code == RobotCommandRejected.plc_code
        await line.acknowledge()
    (intent,) = _intents(tmp_path / "state")
    assert (intent.outcome, intent.cleared) == ("refused", False)


@in_own_event_loop
async def test_a_robot_that_cannot_say_latches_fault_429_until_it_is_settled(tmp_path: Path) -> None:
    robot = HeldByRobot()
    stand_in = FailingWrite(error=DeviceDisconnected("robot: the controller closed the connection"), robot=robot,
                            robot_takes=True)
    stand_in.release.set()
    async with service_on_line(tmp_path, "127.0.46.9", stand_in, devices=_devices(robot)) as (line, _service, _stop):
        robot.reachable = False  # the cable is pulled as the offset goes out; the robot took it
        await _trigger(line, 7)
        status = await line.wait(lambda s: Status.FAULT in s, "FAULT")
        assert not status & (Status.DONE | Status.RESULT_OK | Status.ERROR | Status.READY)
        out = await line.outputs()
        assert (out.result.error_code, out.result.cycle_counter, out.result.part_tag, out.result.offset) == (
            RobotOffsetUnconfirmed.plc_code, 1, 7, ZERO)
        await _fault_reset(line)
        await asyncio.sleep(0.5)
        assert Status.FAULT in await line.status()  # refused: the robot may hold the offset
        assert robot.valid  # the truth: it does
        robot.reachable = True  # the cable is back
        deadline = asyncio.get_running_loop().time() + WAIT_S
        while robot.valid and asyncio.get_running_loop().time() < deadline:
            await asyncio.sleep(0.05)
        assert (robot.sequence, robot.valid) == (0, False)  # settled and cleared
        assert Status.FAULT in await line.status()  # FAULT stays until FAULT_RESET
        await _fault_reset(line)
        await line.wait(lambda s: Status.READY in s, "READY after the settled FAULT")
        stand_in.error = None  # and the line runs on
        await _trigger(line, 8)
        assert await line.wait(lambda s: Status.DONE in s, "DONE") == Status.DONE | Status.RESULT_OK
        assert (await line.outputs()).result.cycle_counter == 2
        await line.acknowledge()
    intents = _intents(tmp_path / "state")
    assert [(i.cycle, i.outcome, i.cleared) for i in intents] == [(1, "held", True), (2, "acknowledged", False)]
    with Journal(tmp_path / "state") as journal:
        assert journal.cycle(1).error_code == RobotOffsetUnconfirmed.code


@pytest.mark.parametrize(("robot_held", "host"), [(True, "127.0.46.10"), (False, "127.0.46.11")],
                         ids=["robot-had-acknowledged", "never-sent"])
@in_own_event_loop
async def test_the_kill_9_window_is_settled_at_the_next_start(tmp_path: Path, robot_held: bool, host: str) -> None:
    """The service died between committing the intent (and maybe the robot's ack) and the cycle's row."""
    state = tmp_path / "state"
    with Journal(state) as journal:
        journal.commit_cycle(_failed_entry())  # cycle 1
        journal.commit_intent(2, 17, OFFSET, [[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 0], [0, 0, 0, 1.0]],
                              job=1, part_tag=3107, started_at=1_790_000_000.0)
    robot = HeldByRobot(sequence=17 if robot_held else 16, valid=robot_held, reachable=False)
    async with plc_line(host) as line, _service(tmp_path, line, StandIn(), _devices(robot)):
        status = await line.wait(lambda s: Status.FAULT in s, "FAULT at start")
        assert Status.READY not in status
        out = await line.outputs()
        assert (out.result.error_code, out.result.cycle_counter) == (RobotOffsetUnconfirmed.plc_code, 2)
        await _fault_reset(line)
        await asyncio.sleep(0.3)
        assert Status.FAULT in await line.status()  # refused while the robot cannot say
        robot.reachable = True
        deadline = asyncio.get_running_loop().time() + WAIT_S
        while robot.asked == 0 or robot.clears == []:
            assert asyncio.get_running_loop().time() < deadline, "not settled"
            await asyncio.sleep(0.05)
        await asyncio.sleep(0.2)
        await _fault_reset(line)
        await line.wait(lambda s: Status.READY in s, "READY once settled")
    (intent,) = _intents(state)
    assert (intent.cycle, intent.outcome, intent.cleared) == (2, "held" if robot_held else "not_held", True)
    assert not robot.valid
    with Journal(state, read_only=True) as journal:  # the rebuilt row: the cycle's facts the intent carried
        row = journal.cycle(2)
    assert (row.job, row.part_tag, row.started_at, row.base_offset_xyzabc) == (1, 3107, 1_790_000_000.0,
                                                                                pytest.approx(list(OFFSET)))


# --- the journal deleted under the service ---------------------------------------------------------------------


@in_own_event_loop
async def test_a_deleted_journal_latches_fault_and_a_new_one_counts_on_from_the_plc(tmp_path: Path) -> None:
    stand_in = StandIn()
    stand_in.release.set()
    state = tmp_path / "state"
    async with plc_line("127.0.46.12") as line:
        async with _service(tmp_path, line, stand_in):
            for tag in (1, 2, 3):
                await _trigger(line, tag)
                await line.wait(lambda s: Status.DONE in s, "DONE")
                await line.acknowledge()
            for suffix in ("", "-wal", "-shm"):
                Path(f"{state / 'journal.sqlite3'}{suffix}").unlink(missing_ok=True)
            await _trigger(line, 4)
            await line.wait(lambda s: Status.FAULT in s, "FAULT")
            out = await line.outputs()
            assert (out.result.error_code, out.result.cycle_counter) == (JournalReplaced.plc_code, 3)
            await _fault_reset(line)
            await asyncio.sleep(0.3)
            assert Status.FAULT in await line.status()  # only a restart clears it
            assert len(stand_in.written) == 3
        async with _service(tmp_path, line, stand_in):  # restarted: a new journal, numbered on from register 13
            await line.control(0)
            await _trigger(line, 5)
            assert await line.wait(lambda s: Status.DONE in s, "DONE") == Status.DONE | Status.RESULT_OK
            assert (await line.outputs()).result.cycle_counter == 4
            await line.acknowledge()
    with Journal(state) as journal:
        assert [row.number for row in journal.last_cycles(10)] == [4]


# --- the PLC's side ---------------------------------------------------------------------------------------------


@in_own_event_loop
async def test_the_abort_code_reaches_the_plc_on_the_next_connection(tmp_path: Path) -> None:
    stand_in = StandIn()
    async with service_on_line(tmp_path, "127.0.46.13", stand_in) as (line, _service, _stop):
        await _trigger(line, 5)
        await line.control(Control.TRIGGER | 0x0010)  # an undefined bit mid-cycle
        await asyncio.sleep(0.2)
        await line.control(Control.TRIGGER)  # the next read is valid again
        status = await line.wait(lambda s: Status.FAULT in s, "FAULT")
        assert not status & Status.DONE
        deadline = asyncio.get_running_loop().time() + WAIT_S
        while (await line.outputs()).result.cycle_counter != 1:
            assert asyncio.get_running_loop().time() < deadline
            await asyncio.sleep(0.02)
        assert (await line.outputs()).result.error_code == PlcValueInvalid.plc_code  # 451, not 403
        await line.control(0)
        await _fault_reset(line)
        await line.wait(lambda s: Status.READY in s, "READY")
    assert stand_in.written == []
    with Journal(tmp_path / "state") as journal:
        assert journal.cycle(1).error_code == PlcValueInvalid.code


@in_own_event_loop
async def test_a_trigger_low_shorter_than_a_poll_is_latched(tmp_path: Path) -> None:
    stand_in = StandIn()
    stand_in.release.set()
    async with service_on_line(tmp_path, "127.0.46.14", stand_in) as (line, _service, _stop):
        await _trigger(line, 1)
        await line.wait(lambda s: Status.DONE in s, "DONE")
        await line.control(Control.RESULT_ACK)  # TRIGGER low with the acknowledgement ...
        await line.wait(lambda s: not s & Status.DONE, "DONE cleared")
        await line.server.write(CONTROL, [0])  # ... then RESULT_ACK low and TRIGGER high again within a few ms
        await line.server.write(3, [2])
        await line.server.write(CONTROL, [int(Control.TRIGGER)])
        status = await line.wait(lambda s: Status.DONE in s, "the next part's DONE")
        assert status == Status.DONE | Status.RESULT_OK
        out = await line.outputs()
        assert (out.result.cycle_counter, out.result.part_tag) == (2, 2)
        await line.acknowledge()


@in_own_event_loop
async def test_a_status_word_overwritten_by_someone_else_is_restored(tmp_path: Path) -> None:
    stand_in = StandIn()
    async with service_on_line(tmp_path, "127.0.46.15", stand_in) as (line, _service, _stop):
        await line.server.write(STATUS, [0])  # another program (a second service on another directory) wrote 0
        await line.wait(lambda s: Status.READY in s, "READY restored", 3.0)


def test_the_ledger_is_not_fooled_by_another_request(tmp_path: Path) -> None:
    """A robot holding another request's offset (an older one) did not take this cycle's."""
    from monoguide.daemon.service import OffsetLedger

    with Journal(tmp_path) as journal:
        journal.commit_intent(1, 41, OFFSET, [])
        ledger = OffsetLedger(journal)
        robot = HeldByRobot(sequence=40, valid=True)
        (settled,) = ledger.settle_pending(robot)  # type: ignore[arg-type]
        assert not settled.held and robot.clears and not robot.valid
        assert journal.intent(1).outcome == "not_held"  # type: ignore[union-attr]
        journal.commit_intent(2, 42, OFFSET, [])
        ledger.unsettled = journal.unsettled_intents()
        robot.reachable = False
        with pytest.raises(DeviceNotFound):
            ledger.settle_pending(robot)  # type: ignore[arg-type]
        assert [i.cycle for i in ledger.unsettled] == [2]


INTENDING = """
import sys, time
from monoguide.daemon.service import Journal, OffsetLedger
journal = Journal(sys.argv[1])
OffsetLedger(journal).intend(7, 23, (1.25, -2.5, 0.75, 0.1, -0.2, 0.3), [], job=4, part_tag=52_117,
                             started_at=1_790_000_123.25)
print("sent", flush=True)  # the offset went to the robot; the service dies before the cycle's row
time.sleep(30)
"""


def test_the_row_rebuilt_after_a_kill_9_carries_the_cycles_job_part_tag_and_start(tmp_path: Path) -> None:
    child = subprocess.Popen([sys.executable, "-c", INTENDING, str(tmp_path)], stdout=subprocess.PIPE, text=True)
    assert child.stdout is not None and child.stdout.readline() == "sent\n"
    child.send_signal(signal.SIGKILL)
    assert child.wait(timeout=5) == -signal.SIGKILL
    child.stdout.close()
    from monoguide.daemon.service import OffsetLedger

    with Journal(tmp_path) as journal:  # the next start
        ledger = OffsetLedger(journal)
        assert ledger.recover() == [7]
        (intent,) = ledger.unsettled
        row = journal.cycle(7)
    assert (row.job, row.part_tag, row.started_at, row.finished_at) == (4, 52_117, 1_790_000_123.25,
                                                                        intent.intended_at)
    assert (row.error_code, row.plc_code) == (RobotOffsetUnconfirmed.code, RobotOffsetUnconfirmed.plc_code)
    assert row.error_message is not None and row.error_message.startswith("cycle 7 (job 4, part tag 52117): ")
    assert row.base_offset_xyzabc == list(OFFSET) and row.damaged == ()
