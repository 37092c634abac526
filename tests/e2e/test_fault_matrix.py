"""The fault matrix: every fault the simulated cell offers (device, PLC, robot, calibration, signal, disk, journal) in
the phase it strikes (idle, moving, capturing, solving, writing the offset, waiting for the robot's ack, awaiting the
PLC's acknowledgement), one row each, run against the real service over the real transports — `monoguide sim-cell`
(the simulated UR controller, its part supply and truth), `monoguide run` as its own process (its state directory on
a tmpfs of its own, so that a disk can really fill), the PLC played here over the real pymodbus server.

For each row, whatever the fault:
- the journal has the cycle it ended (its number the one register 13 shows), with a code the row expects, and with
  its images on disk where a frame was taken before the fault struck (its views, and where it failed);
- the PLC saw that code (register 11, with DONE + ERROR, or with FAULT where the row latches it);
- the robot holds no offset the PLC was not told RESULT_OK about (the controller's own truth file);
- READY comes back (after FAULT_RESET where FAULT latched), and the next part is measured RESULT_OK;
- the service's resident memory is back at its level after that good cycle (failed cycles keep nothing).

New faults and phases add rows to :data:`ROWS`. The table of what each row saw is printed at the end (``-s``), and
written to ``$MONOGUIDE_FAULT_MATRIX`` when that names a file.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import signal
import statistics
import subprocess
import sys
import time
from collections.abc import Awaitable, Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
from helpers.cell_configs import cell_config
from helpers.disks import fill, small_file_system
from helpers.plc_line import Line, in_own_event_loop, plc_line
from helpers.sim_processes import keep_reading, start_sim_cell, stop

from monoguide.daemon.service import Journal
from monoguide.daemon.simulate import sample_process
from monoguide.drivers.plc_registers import Control, Status
from monoguide.drivers.sim.robot_truth import read_truth

pytestmark = pytest.mark.slow

ROBOT_HOST, PLC_HOST, PLC_PORT = "127.0.90.10", "127.0.90.11", 5020
START_S = 60.0  # the service's start with its devices, on a loaded machine
CYCLE_S = 60.0
MEMORY_SLACK_MB = 12.0  # above the level of the good cycles before the faults: less than half a failed cycle's frames
STATE_DISK_KB = 256 * 1024  # the service's state directory: images pruned beyond 60 MB, room for a fault's filler


@dataclass
class Seen:
    """What the PLC saw of the row's cycle, and what the journal and the robot say of it."""

    status: Status | None = None  # the status word at the row's end (DONE + ..., FAULT)
    error_code: int | None = None  # register 11 then
    counter: int | None = None  # register 13 then
    row_code: str | None = None  # the journal's row of that cycle
    images: int = 0  # its image files on disk
    stage: str | None = None  # the stage its result says it failed in
    notes: list[str] = field(default_factory=list)


@dataclass(frozen=True)
class Row:
    """One fault in one phase: how it is played, and what it may end in."""

    fault: str
    phase: str
    play: Callable[[Cell], Awaitable[Seen]]
    codes: frozenset[str] = frozenset()  # what the cycle may be journaled with (empty: no cycle, or an ok one)
    plc_codes: frozenset[int] = frozenset()  # register 11 at the end (empty: the plc_code of the journal's code)
    latches: bool | None = False  # FAULT at the end (then FAULT_RESET); None: it may
    images: bool = False  # the cycle journals at least one image


class Cell:
    """The simulated cell, the service and the PLC of the matrix."""

    def __init__(self, tmp: Path, config: Path, state_dir: Path, sim: subprocess.Popen[str], sim_lines: list[str],
                 robot_truth: Path, line: Line) -> None:
        self.tmp, self.config, self.state_dir, self.sim, self.sim_lines = tmp, config, state_dir, sim, sim_lines
        self.robot_truth, self.line = robot_truth, line
        self.service: subprocess.Popen[bytes] | None = None
        self.log = tmp / "service.log"
        self.reported_ok: set[int] = set()  # the robot sequence numbers the PLC was told RESULT_OK about
        self.level_mb: float | None = None
        self.tag = 1000

    # --- the service ---------------------------------------------------------------------------------

    def start_service(self) -> None:
        with open(self.log, "ab") as log:
            self.service = subprocess.Popen([sys.executable, "-m", "monoguide.daemon.cli", "run", "--config",
                                             str(self.config), "--state-dir", str(self.state_dir)],
                                            stdout=subprocess.DEVNULL, stderr=log)
        self.level_mb = None

    async def end_service(self, signum: int = signal.SIGTERM) -> int:
        assert self.service is not None
        self.service.send_signal(signum)
        code = await asyncio.to_thread(self.service.wait, 30)
        self.service = None
        return code

    def rss_mb(self) -> float:
        assert self.service is not None
        sample = sample_process(self.service.pid)
        assert sample is not None, "the service is gone"
        return sample["rss_mb"]

    # --- the simulated devices -------------------------------------------------------------------------

    async def sim_command(self, command: str) -> None:
        """A line to sim-cell's standard input, waited for until taken up: echoed (camera, calibration) or counted
        by the robot controller."""
        device = command.split()[0]
        applied = self.robot().get("commands_applied", 0) if device == "robot" else None
        echoed = len(self.sim_lines)
        assert self.sim.stdin is not None
        self.sim.stdin.write(command + "\n")
        self.sim.stdin.flush()
        deadline = time.monotonic() + 10.0
        while True:
            if device == "robot":
                if int(self.robot().get("commands_applied", 0)) > int(applied or 0):
                    return
            elif any(line.startswith("fault:") for line in self.sim_lines[echoed:]):
                return
            assert time.monotonic() < deadline, f"sim-cell did not take up {command!r}: {self.sim_lines[-3:]}"
            await asyncio.sleep(0.01)

    def robot(self) -> dict[str, Any]:
        for _ in range(100):
            with contextlib.suppress(OSError, ValueError):
                return read_truth(self.robot_truth)
        raise AssertionError("no robot truth file")

    # --- the PLC's side ----------------------------------------------------------------------------------

    async def trigger(self, job: int = 1) -> None:
        self.tag += 1
        await self.line.trigger(job=job, tag=self.tag, timeout_s=START_S)

    async def end(self, timeout_s: float = CYCLE_S) -> Seen:
        """Wait for the cycle's end the PLC sees (DONE or FAULT) and read what it shows."""
        status = await self.line.wait(lambda s: bool(s & (Status.DONE | Status.FAULT)), "DONE or FAULT", timeout_s)
        out = (await self.line.outputs()).result
        return Seen(status, out.error_code, out.cycle_counter)

    async def acknowledge(self) -> None:
        """RESULT_ACK, then both bits low, as the PLC does (READY is waited for by :meth:`ready`)."""
        await self.line.control(Control.RESULT_ACK)
        await self.line.wait(lambda s: not s & (Status.DONE | Status.RESULT_OK | Status.ERROR), "DONE cleared")
        await self.line.control(0)

    async def ready(self, timeout_s: float = START_S) -> None:
        """READY: DONE acknowledged, FAULT_RESET pulsed while FAULT is shown (ignored until it can clear)."""
        deadline = time.monotonic() + timeout_s
        while Status.READY not in (status := await self.line.status()):
            assert time.monotonic() < deadline, f"no READY within {timeout_s:g} s (status {status!r})"
            if Status.DONE in status:
                await self.acknowledge()
            elif Status.FAULT in status:
                await self.line.control(Control.FAULT_RESET)
                await asyncio.sleep(0.1)
                await self.line.control(0)
            await asyncio.sleep(0.2)

    async def good_cycle(self) -> Seen:
        await self.ready()
        await self.trigger()
        seen = await self.end()
        assert seen.status == Status.DONE | Status.RESULT_OK, f"the good cycle after the fault: {seen}"
        with Journal(self.state_dir, read_only=True) as journal:
            intent = journal.intent(journal.cycle_counter())
        assert intent is not None and intent.outcome == "acknowledged"
        self.reported_ok.add(intent.sequence)
        await self.acknowledge()
        return seen


# --- the rows ---------------------------------------------------------------------------------------------


def device_fault(command: str | None, clear: str | None = None, job: int = 1) -> Callable[[Cell], Awaitable[Seen]]:
    """A fault of sim-cell's (``camera X 1``, ``robot X``) armed while idle: it strikes the next cycle where it
    strikes (the next grab, the next request, the next offset); then cleared. None: no fault, only PLC job ``job``."""

    async def play(cell: Cell) -> Seen:
        await cell.ready()
        if command is not None:
            await cell.sim_command(command)
        await cell.trigger(job)
        seen = await cell.end()
        if clear is not None:
            await cell.sim_command(clear)
        return seen

    return play


async def robot_lost_while_idle(cell: Cell) -> Seen:
    """The controller's connections cut while the cell waits for a trigger: READY falls within a second, and comes
    back once the robot answers again (no cycle)."""
    await cell.ready()
    await asyncio.sleep(0.3)
    await cell.sim_command("robot cut 1.5")
    await cell.line.wait(lambda s: Status.READY not in s, "READY gone after the cut", 1.0)
    return Seen(notes=["READY off within 1 s"])


async def trigger_dropped_while_moving(cell: Cell) -> Seen:
    await cell.ready()
    await cell.trigger()
    await asyncio.sleep(0.15)
    await cell.line.control(0)
    return await cell.end()


async def heartbeat_stops_while_idle(cell: Cell) -> Seen:
    await cell.ready()
    cell.line.beating = False
    try:
        seen = await cell.end(timeout_s=10.0)
    finally:
        cell.line.beating = True
    return seen


async def heartbeat_stops_awaiting_the_acknowledgement(cell: Cell) -> Seen:
    return await _unacknowledged(cell, stop_heartbeat=True)


async def no_acknowledgement(cell: Cell) -> Seen:
    return await _unacknowledged(cell, stop_heartbeat=False)


async def _unacknowledged(cell: Cell, stop_heartbeat: bool) -> Seen:
    """A good cycle's DONE + RESULT_OK read and never acknowledged (TRIGGER kept high): FAULT after the PLC's
    acknowledgement timeout — or, with the heartbeat stopped meanwhile, after the heartbeat's."""
    await cell.ready()
    await cell.trigger()
    done = await cell.end()
    assert done.status == Status.DONE | Status.RESULT_OK, done
    _note_reported(cell)
    cell.line.beating = not stop_heartbeat
    try:
        await cell.line.wait(lambda s: Status.FAULT in s, "FAULT", 15.0)
    finally:
        cell.line.beating = True
    seen = await cell.end()
    await cell.line.control(0)
    return seen


async def sigterm_while_moving(cell: Cell) -> Seen:
    await cell.ready()
    await cell.trigger()
    await asyncio.sleep(0.15)
    assert cell.service is not None
    cell.service.send_signal(signal.SIGTERM)
    seen = await cell.end()
    await cell.acknowledge()
    code = await asyncio.to_thread(cell.service.wait, 30)
    cell.service = None
    assert await cell.line.status() == Status(0), "a stopped service shows 0"
    seen.notes.append(f"exit {code}, status word 0")
    cell.start_service()
    return seen


async def kill_9_awaiting_the_robots_ack(cell: Cell) -> Seen:
    """The controller takes no offset (no-ack) and the service is killed while it waits: at the next start the intent
    gets its row (429) and is settled with the robot before the cell is READY again."""
    await cell.ready()
    await cell.sim_command("robot no-ack")
    offsets = len(cell.robot().get("offsets", []))
    number = _journal_counter(cell) + 1
    await cell.trigger()
    await _offset_sent(cell, number)
    await asyncio.sleep(0.3)  # sent, and not acknowledged (no-ack)
    assert cell.service is not None
    cell.service.kill()
    await asyncio.to_thread(cell.service.wait, 30)
    cell.service = None
    await cell.sim_command("robot none")
    await cell.line.control(0)
    cell.start_service()
    seen = await cell.end(timeout_s=START_S)
    seen.notes.append(f"offsets taken by the controller meanwhile: {len(cell.robot().get('offsets', [])) - offsets}")
    return seen


def calibration_fault(command: str, clear: str) -> Callable[[Cell], Awaitable[Seen]]:
    async def play(cell: Cell) -> Seen:
        await cell.ready()
        await cell.sim_command(command)
        await cell.trigger()
        seen = await cell.end()
        await cell.sim_command(clear)
        await cell.acknowledge()
        done = subprocess.run([sys.executable, "-m", "monoguide.daemon.cli", "health", "--state-dir",
                               str(cell.state_dir), "--clear", "fault matrix: the camera is back on its bracket"],
                              capture_output=True, text=True, timeout=60)
        assert done.returncode == 0, done.stderr
        return seen

    return play


async def disk_full_at_the_intent(cell: Cell) -> Seen:
    """The state directory's disk full: the offset's intent cannot be committed, so nothing is sent; FAULT names the
    journal; space freed, FAULT_RESET commits the cycle's row and clears it."""
    await cell.ready()
    filler = fill(cell.state_dir)
    try:
        await cell.trigger()
        seen = await cell.end()
    finally:
        filler.unlink()
    return seen


async def disk_full_while_reporting(cell: Cell) -> Seen:
    """The disk fills while the robot is asked for its ack (no-ack): the write fails and is settled with the robot
    (it holds nothing), then the cycle's row cannot be committed: FAULT names the journal, nothing is held; space
    freed, FAULT_RESET commits the cycle's row and the offset's outcome, and clears it."""
    await cell.ready()
    await cell.sim_command("robot no-ack")
    number = _journal_counter(cell) + 1
    await cell.trigger()
    await _offset_sent(cell, number)
    filler = fill(cell.state_dir)
    try:
        seen = await cell.end()
    finally:
        filler.unlink()
        await cell.sim_command("robot none")
    return seen


async def _offset_sent(cell: Cell, number: int) -> None:
    """Until cycle ``number``'s offset intent is committed (just before the offset goes to the controller)."""
    deadline = time.monotonic() + CYCLE_S
    while True:
        with Journal(cell.state_dir, read_only=True) as journal:
            if journal.intent(number) is not None:
                return
        assert time.monotonic() < deadline, "the offset was never sent"
        await asyncio.sleep(0.01)


async def journal_deleted_while_idle(cell: Cell) -> Seen:
    """The journal deleted under the running service: the next trigger latches FAULT (nothing moves), FAULT_RESET
    cannot clear it; the restarted service opens a new journal that counts on from register 13."""
    await cell.ready()
    for name in ("journal.sqlite3", "journal.sqlite3-wal", "journal.sqlite3-shm"):
        (cell.state_dir / name).unlink(missing_ok=True)
    await cell.trigger()
    seen = await cell.end()
    counter = seen.counter
    await cell.line.control(0)
    code = await cell.end_service()
    seen.notes.append(f"restarted (exit {code}); counts on after {counter}")
    cell.start_service()
    await cell.ready()
    return seen


def _note_reported(cell: Cell) -> None:
    with Journal(cell.state_dir, read_only=True) as journal:
        intent = journal.intent(journal.cycle_counter())
    if intent is not None and intent.outcome == "acknowledged":
        cell.reported_ok.add(intent.sequence)


CAMERA_CODES = {
    "timeout": {"DEVICE_TIMEOUT"},
    "disconnect": {"DEVICE_DISCONNECTED", "DEVICE_NOT_FOUND"},
    "black": {"LOW_CONTRAST", "HOLE_NOT_FOUND", "FEATURE_NOT_FOUND"},
    "occluded": {"HOLE_NOT_FOUND", "LOW_CONTRAST", "FEATURE_NOT_FOUND", "HOLE_AMBIGUOUS"},
    "glare": {"IMAGE_SATURATED", "HOLE_NOT_FOUND", "HOLE_AMBIGUOUS", "RESIDUAL_TOO_LARGE", "INCONSISTENT_MEASUREMENT",
              "FEATURE_NOT_FOUND"},
}
ROWS: tuple[Row, ...] = (
    *(Row(f"camera {name}", "capturing", device_fault(f"camera {name} 1"), frozenset(codes),
          images=name in ("black", "occluded", "glare")) for name, codes in CAMERA_CODES.items()),
    Row("robot stall", "moving", device_fault("robot stall", "robot none"),
        frozenset({"ROBOT_POSITION_TIMEOUT", "DEVICE_TIMEOUT", "DEVICE_DISCONNECTED"})),
    Row("robot drop", "moving", device_fault("robot drop", "robot none"),
        frozenset({"DEVICE_DISCONNECTED", "ROBOT_NOT_READY", "DEVICE_TIMEOUT"})),
    Row("robot protective-stop", "moving", device_fault("robot protective-stop", "robot none"),
        frozenset({"ROBOT_PROTECTIVE_STOP"})),
    Row("robot never-reach", "moving", device_fault("robot never-reach", "robot none"),
        frozenset({"ROBOT_POSITION_TIMEOUT"})),
    Row("robot program-stopped", "moving", device_fault("robot program-stopped", "robot none"),
        frozenset({"ROBOT_NOT_READY"})),
    Row("robot no-ack", "waiting for the robot's ack", device_fault("robot no-ack", "robot none"),
        frozenset({"ROBOT_ACK_TIMEOUT"}), images=True),
    Row("robot cut 1 s after the offset", "writing the offset", device_fault("robot cut-after-offset 0 1.0", None),
        frozenset({"DEVICE_DISCONNECTED", "DEVICE_TIMEOUT", "ROBOT_ACK_TIMEOUT", "ROBOT_OFFSET_UNCONFIRMED",
                   "ROBOT_WORKER_CRASHED"}), latches=None, images=True),
    Row("robot link cut", "idle", robot_lost_while_idle),
    Row("job of another part type", "capturing", device_fault(None, None, job=2),
        frozenset({"HOLE_NOT_FOUND", "LOW_CONTRAST", "FEATURE_NOT_FOUND", "HOLE_AMBIGUOUS", "HOLE_CUT_BY_BORDER",
                   "ROBOT_POSE_MISMATCH", "CYCLE_UNEXPECTED", "INCONSISTENT_MEASUREMENT", "RESIDUAL_TOO_LARGE"})),
    Row("plc trigger dropped", "moving", trigger_dropped_while_moving, frozenset({"PLC_TRIGGER_DROPPED"})),
    Row("plc heartbeat stopped", "idle", heartbeat_stops_while_idle, plc_codes=frozenset({452}), latches=True),
    Row("plc heartbeat stopped", "awaiting the PLC's acknowledgement", heartbeat_stops_awaiting_the_acknowledgement,
        plc_codes=frozenset({452}), latches=True),
    Row("plc no acknowledgement", "awaiting the PLC's acknowledgement", no_acknowledgement,
        plc_codes=frozenset({454}), latches=True),
    Row("signal SIGTERM", "moving", sigterm_while_moving, frozenset({"CYCLE_ABORTED"})),
    Row("signal SIGKILL", "waiting for the robot's ack", kill_9_awaiting_the_robots_ack,
        frozenset({"ROBOT_OFFSET_UNCONFIRMED"}), latches=True),
    Row("calibration camera bump 1 deg", "solving", calibration_fault("camera bump 1 0", "camera bump 0 0"),
        frozenset({"CALIBRATION_SUSPECT", "INCONSISTENT_MEASUREMENT", "RESIDUAL_TOO_LARGE", "HOLE_NOT_FOUND",
                   "OFFSET_OUT_OF_ENVELOPE"}), images=True),
    Row("disk full", "writing the offset", disk_full_at_the_intent, frozenset({"JOURNAL_ERROR"}),
        plc_codes=frozenset({620}), latches=True),
    Row("disk full", "reporting", disk_full_while_reporting, frozenset({"ROBOT_ACK_TIMEOUT"}),
        plc_codes=frozenset({620}), latches=True, images=True),
    Row("journal deleted", "idle", journal_deleted_while_idle, plc_codes=frozenset({625}), latches=True),
)


# --- the test -----------------------------------------------------------------------------------------------


@pytest.fixture
def matrix_dir(tmp_path: Path) -> Iterator[Path]:
    with small_file_system(tmp_path / "state", STATE_DISK_KB) as state:
        yield state


@pytest.mark.timeout(900)
@in_own_event_loop
async def test_every_fault_in_every_phase_ends_journaled_told_and_released(tmp_path: Path, matrix_dir: Path) -> None:
    state_file = tmp_path / "sim-state.json"
    config = cell_config(tmp_path, ROBOT_HOST, PLC_HOST, sharp=True, state_file=state_file,
                         more=[("heartbeat_timeout_s = 2.0", "heartbeat_timeout_s = 1.0\nack_timeout_s = 3.0"),
                               ("move_timeout_s = 10.0", "move_timeout_s = 3.0")],
                         extra="\n[service]\nimages_max_mb = 60.0\n")
    sim, _ = start_sim_cell(config, "--no-plc", "--truth-log", str(tmp_path / "truth.jsonl"), stdin=subprocess.PIPE,
                            timeout_s=START_S)
    sim_lines = keep_reading(sim)
    table: list[tuple[Row, Seen, list[str]]] = []
    try:
        async with plc_line(PLC_HOST, PLC_PORT) as line:
            cell = Cell(tmp_path, config, matrix_dir, sim, sim_lines,
                        state_file.with_name(state_file.stem + "-robot-truth.json"), line)
            cell.start_service()
            try:
                await _level(cell)
                only = os.environ.get("MONOGUIDE_FAULT_MATRIX_ROWS")  # a developer's run of some rows: "camera,robot"
                for row in ROWS:
                    if only is None or any(word in row.fault for word in only.split(",")):
                        table.append(await _play(cell, row))
            finally:
                if cell.service is not None:
                    await cell.end_service()
    finally:
        stop(sim, 15.0)
        _print(table, tmp_path)
    failed = [(row, problems) for row, _, problems in table if problems]
    assert not failed, "\n".join(f"{row.fault} @ {row.phase}: {'; '.join(p)}" for row, p in failed) + "\n" + \
        (tmp_path / "service.log").read_text()[-4000:]


async def _level(cell: Cell) -> None:
    """The service's memory level: the median over good cycles (after a first few that warm it up)."""
    samples = []
    for k in range(5):
        await cell.good_cycle()
        if k >= 2:
            samples.append(cell.rss_mb())
    cell.level_mb = statistics.median(samples)


async def _play(cell: Cell, row: Row) -> tuple[Row, Seen, list[str]]:
    problems: list[str] = []
    before = _journal_counter(cell)
    try:
        seen = await row.play(cell)
    except AssertionError as exc:
        return row, Seen(notes=[f"play: {exc}"]), [f"the row did not play: {exc}"]
    if cell.service is not None and cell.level_mb is not None:
        seen.notes.append(f"rss after the fault {cell.rss_mb():.0f} MB")
        if os.environ.get("MONOGUIDE_FAULT_MATRIX_RSS"):
            status = Path(f"/proc/{cell.service.pid}/status").read_text().splitlines()
            seen.notes.append(" ".join(x.replace("\t", "").replace(" kB", "") for x in status if x.startswith("Rss")))
    try:
        await cell.ready()  # FAULT_RESET where it latched: the journal takes what it could not before
    except AssertionError as exc:
        problems.append(f"no READY: {exc}")
    _check_cycle(cell, row, seen, before, problems)
    try:
        if cell.level_mb is None:  # restarted: its level anew
            await _level(cell)
        else:
            await cell.good_cycle()
            rss = cell.rss_mb()
            seen.notes.append(f"rss {rss:.0f} MB (level {cell.level_mb:.0f})")
            if rss > cell.level_mb + MEMORY_SLACK_MB:
                problems.append(f"memory {rss:.1f} MB after a good cycle, level {cell.level_mb:.1f} MB")
    except AssertionError as exc:
        problems.append(f"no recovery: {exc}")
    _check_robot(cell, problems)
    return row, seen, problems


def _check_cycle(cell: Cell, row: Row, seen: Seen, before: int, problems: list[str]) -> None:
    if row.latches is not None and row.latches != bool(seen.status is not None and Status.FAULT in seen.status):
        problems.append(f"status {seen.status!r}: expected {'FAULT' if row.latches else 'no FAULT'}")
    with Journal(cell.state_dir, read_only=True) as journal:
        counter = journal.cycle_counter()
        rows = [journal.cycle(n) for n in range(max(before, counter - 5) + 1, counter + 1) if journal.has_cycle(n)]
    failed = [r for r in rows if r.status == "error"]
    if row.codes:
        if not failed:
            problems.append(f"no failed cycle journaled (counter {before} -> {counter})")
            return
        journaled = failed[-1]
        seen.row_code, seen.stage = journaled.error_code, ((journaled.result or {}).get("failure") or {}).get("stage")
        if journaled.error_code not in row.codes:
            problems.append(f"journaled {journaled.error_code}, expected one of {sorted(row.codes)}")
        if seen.counter is not None and not row.plc_codes and seen.counter != journaled.number % 65536:
            problems.append(f"register 13 = {seen.counter}, the journal's row is {journaled.number}")
        if seen.error_code != journaled.plc_code and not (row.latches and row.plc_codes):
            problems.append(f"register 11 = {seen.error_code}, the journal's row has {journaled.plc_code}")
        paths = [cell.state_dir / p for p in journaled.image_paths]
        seen.images = sum(1 for p in paths if p.is_file())
        if row.images and not seen.images:
            problems.append(f"no image on disk ({journaled.image_paths})")
        if seen.images != len(paths):
            problems.append(f"{len(paths) - seen.images} of its images missing on disk")
    if row.plc_codes and seen.error_code not in row.plc_codes:
        problems.append(f"register 11 = {seen.error_code}, expected one of {sorted(row.plc_codes)}")


def _check_robot(cell: Cell, problems: list[str]) -> None:
    truth = cell.robot()
    if truth.get("offset_valid") and truth.get("held_sequence") not in cell.reported_ok:
        problems.append(f"the robot holds offset {truth.get('held_sequence')}, the PLC was told RESULT_OK of "
                        f"{sorted(cell.reported_ok)[-5:]}")


def _journal_counter(cell: Cell) -> int:
    with contextlib.suppress(Exception), Journal(cell.state_dir, read_only=True) as journal:
        return journal.cycle_counter()
    return 0


def _print(table: list[tuple[Row, Seen, list[str]]], tmp_path: Path) -> None:
    lines = ["| fault | phase | PLC saw | journaled | stage | images | robot, READY, memory |",
             "|---|---|---|---|---|---|---|"]
    for row, seen, problems in table:
        plc = "-" if seen.status is None else f"{seen.status.name} {seen.error_code}"
        verdict = "; ".join(problems) if problems else "ok"
        lines.append(f"| {row.fault} | {row.phase} | {plc} | {seen.row_code or '-'} | {seen.stage or '-'} | "
                     f"{seen.images} | {verdict}; {', '.join(seen.notes)} |")
    text = "\n".join(lines)
    print("\n" + text)
    if out := os.environ.get("MONOGUIDE_FAULT_MATRIX"):
        Path(out).write_text(text + "\n")
    (tmp_path / "fault-matrix.md").write_text(text + "\n")
