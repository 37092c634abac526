"""One ``monoguide simulate`` run: the simulated cell and the service as two child processes, as on a line.

``monoguide sim-cell`` (the simulated PLC playing N parts, the robot controller with the part supply and
its truth log, the tracker) starts first; once it says where its devices listen, ``monoguide run --cycles
N`` starts against the same derived config (with ``--faults`` without ``--cycles``: it is stopped after the
last part). Progress comes from the line: the simulated PLC's record of every part it played (``plc:
{...}`` on sim-cell's standard output). With ``--faults`` each device and PLC fault is sent to sim-cell's
standard input in turn, between good cycles, then the calibration faults, each for a few parts
(:mod:`._fault_plan`). The service's resident memory, threads and open files are sampled from ``/proc`` while it
runs (the last sample is "at the end").

Every wait has a deadline and says what it waited for; Ctrl-C or SIGTERM stops the service first, then the
cell (:class:`~._children.Children`), and so does every other way the run ends.
"""

from __future__ import annotations

import contextlib
import json
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from monoguide.daemon.errors import SimulateChildEnded, SimulateTimeout
from monoguide.daemon.service import JournalRow
from monoguide.daemon.service._health import request_clear
from monoguide.daemon.simulate._children import STOP_TIMEOUT_S, Child, Children, LineReader
from monoguide.daemon.simulate._config import DerivedCell, derive_config
from monoguide.daemon.simulate._fault_plan import Fault, FaultInjector, InjectedFault, faults_to_inject
from monoguide.daemon.simulate._sampling import sample_process
from monoguide.daemon.simulate._witnesses import logged_codes, read_journal_rows, read_truth_log
from monoguide.drivers.errors import ConfigError

CELL_START_TIMEOUT_S = 90.0  # building the cell and starting three device processes on a busy machine
SERVICE_START_TIMEOUT_S = 60.0  # service start + devices connected + first part finished
PART_TIMEOUT_S = 60.0  # no part finished for this long: something hangs
FAULT_PART_TIMEOUT_S = 90.0  # with --faults: the line waits up to 30 s for READY after a fault
SERVICE_EXIT_TIMEOUT_S = 15.0
POLL_S = 0.1


@dataclass(frozen=True)
class RunOptions:
    config: Path
    work_dir: Path
    cycles: int = 24
    seed: int | None = None
    robot: str | None = None
    perfect_robot: bool = False
    faults: bool = False
    host: str | None = None
    fault_names: tuple[str, ...] = ()  # "device name" of FAULT_PLAN, or calibration faults, to inject (empty: all)
    calibration: Path | None = None  # the service runs with this file's calibration values (the cell: config's)
    jobs: tuple[int, ...] = ()  # the part types the line brings, in turn (empty: every job of the config in turn)
    fail_every: int = 0  # one part in this many meets a one-grab camera failure (0: none); with or without faults


@dataclass
class RunResult:
    cell: DerivedCell
    plc_records: list[dict[str, Any]]
    journal_rows: list[JournalRow]
    truth: list[dict[str, Any]]
    faults: list[InjectedFault]
    samples: list[dict[str, float]]
    logged_codes: set[str]
    service_exit: int | None
    elapsed_s: float

    @property
    def rss(self) -> dict[str, float] | None:
        if not self.samples:
            return None
        return {"rss_mb": self.samples[-1]["rss_mb"], "rss_max_mb": max(s["rss_mb"] for s in self.samples)}


@dataclass
class Progress:
    """Callbacks the command gives: ``part(done, total, record)`` per finished part, ``note(text)`` per phase."""

    part: Callable[[int, int, dict[str, Any]], None] = lambda done, total, record: None
    note: Callable[[str], None] = lambda text: None
    sample: Callable[[dict[str, float]], None] = lambda sample: None


def run_simulation(options: RunOptions, progress: Progress | None = None) -> RunResult:
    """Run the cell and the service for ``options.cycles`` parts; see the module's doc."""
    progress = progress or Progress()
    started = time.monotonic()
    cell = derive_config(options.config, options.work_dir, seed=options.seed, robot=options.robot,
                         perfect_robot=options.perfect_robot, host=options.host, faults=options.faults,
                         calibration=options.calibration, jobs=options.jobs)
    plan = faults_to_inject(options.fault_names) if options.faults else ()
    _check_poses(plan, cell)
    cell.state_dir.mkdir(parents=True, exist_ok=True)
    logs = options.work_dir.resolve()
    with _sigterm_interrupts(), Children() as children:
        progress.note(f"starting the simulated cell on {cell.host} (config {cell.config})")
        sim = children.start("simulated cell", [
            sys.executable, "-m", "monoguide.daemon.cli", "sim-cell", "--config", str(cell.config), "--truth-log",
            str(cell.truth_log), "--parts", str(options.cycles), "--part-types", ",".join(map(str, cell.jobs))],
            logs / "sim-cell.log", commands=True)
        _wait_listening(sim)
        # --cycles N: the service stops by itself after N cycles, as a line's test run would. With --faults a
        # part may end without a cycle (or with two), so the service runs until stopped after the last part.
        until = () if options.faults else ("--cycles", str(options.cycles))
        calibrated = f"; calibration of {options.calibration}, config {cell.service}" if cell.calibration else ""
        progress.note(f"starting the service: monoguide run {' '.join(until)} (state {cell.state_dir}{calibrated})")
        service = children.start("service", [
            sys.executable, "-m", "monoguide.daemon.cli", "run", "--config", str(cell.service), "--state-dir",
            str(cell.state_dir), *until], logs / "service.log")
        records, faults, samples = _play(options, cell, sim, service, progress, plan)
        service_exit = _finish_service(service, progress, by_itself=not options.faults)
    return RunResult(cell, records, read_journal_rows(cell.state_dir), read_truth_log(cell.truth_log, grasps=True),
                     faults, samples, logged_codes(service.log), service_exit, time.monotonic() - started)


# --- private ------------------------------------------------------------------------------------


@contextlib.contextmanager
def _sigterm_interrupts() -> Iterator[None]:
    """SIGTERM ends the run as Ctrl-C does (KeyboardInterrupt: the children are stopped on the way out)."""
    previous = signal.signal(signal.SIGTERM, _raise_interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _raise_interrupt(_signum: int, _frame: object) -> None:
    raise KeyboardInterrupt


def _wait_listening(sim: Child) -> None:
    """Until sim-cell prints ``state file ...`` (it does once every device listens)."""
    lines = _lines(sim)
    deadline = time.monotonic() + CELL_START_TIMEOUT_S
    while time.monotonic() < deadline:
        line = lines.get(POLL_S)
        if line is None or sim.ended() is not None:
            raise SimulateChildEnded(f"the simulated cell ended (status {sim.process.wait()}) before its devices "
                                     f"listened; {sim.log}: {sim.tail()}")
        if line.startswith("state file "):
            return
    raise SimulateTimeout(f"the simulated cell did not say its devices listen within {CELL_START_TIMEOUT_S:g} s; "
                          f"its output: {' | '.join(lines.seen[-5:]) or '(none)'}; {sim.log}: {sim.tail()}")


def _check_poses(plan: tuple[Fault, ...], cell: DerivedCell) -> None:
    """A pose drift names a robot pose number the run's cell has (a :class:`ConfigError` before anything starts)."""
    poses = len(cell.data.get("measuring_poses", ()))
    for device, name, _ in plan:
        if device == "pose" and not 1 <= int(name.split()[1]) <= poses:
            raise ConfigError(f"--fault '{device} {name}': pose number {name.split()[1]}: the cell "
                              f"{cell.config} has measuring poses 1 to {poses}")


def _play(options: RunOptions, cell: DerivedCell, sim: Child, service: Child, progress: Progress,
          plan: tuple[Fault, ...]) -> tuple[list[dict[str, Any]], list[InjectedFault], list[dict[str, float]]]:
    """Collect the line's records of ``options.cycles`` parts, injecting faults, sampling the service."""
    total, lines = options.cycles, _lines(sim)
    records: list[dict[str, Any]] = []
    samples: list[dict[str, float]] = []
    injector = FaultInjector(sim.send, total, plan, float(cell.data["plc"].get("heartbeat_timeout_s", 2.0)),
                             progress.note, lambda why: request_clear(cell.state_dir, why), options.fail_every)
    part_timeout = FAULT_PART_TIMEOUT_S if options.faults else PART_TIMEOUT_S
    deadline = time.monotonic() + SERVICE_START_TIMEOUT_S + part_timeout
    service_gone_at: float | None = None
    while len(records) < total:
        injector.before_part(len(records), time.monotonic())
        line = lines.get(POLL_S)
        if (sample := sample_process(service.process.pid)) is not None and service.ended() is None:
            samples.append(sample)
            progress.sample(sample)
        if line is None:
            raise SimulateChildEnded(f"the simulated cell ended (status {sim.process.wait()}) after {len(records)} "
                                     f"of {total} parts; {sim.log}: {sim.tail()}")
        if line.startswith("plc: "):
            record = json.loads(line[len("plc: "):])
            records.append(record)
            progress.part(len(records), total, record)
            deadline = time.monotonic() + part_timeout
            injector.part_done()
            continue
        if sim.ended() is not None:
            raise SimulateChildEnded(f"the simulated cell ended (status {sim.process.returncode}) after "
                                     f"{len(records)} of {total} parts; {sim.log}: {sim.tail()}")
        status = service.ended()
        if status is not None and status != 0:
            raise SimulateChildEnded(f"the service ended with status {status} after {len(records)} of {total} "
                                     f"parts; {service.log}: {service.tail()}")
        if status == 0 and service_gone_at is None:  # --cycles reached: the line's last records are on their way
            service_gone_at = time.monotonic()
            deadline = min(deadline, service_gone_at + SERVICE_EXIT_TIMEOUT_S)
        if time.monotonic() > deadline:
            raise SimulateTimeout(f"the service did not finish {total} cycles in time: {len(records)} parts done, "
                                  f"none for {part_timeout:g} s; last state: {service.tail(3)}; the line: "
                                  f"{' | '.join(lines.seen[-2:])}")
    return records, injector.injected, samples


def _lines(sim: Child) -> LineReader:
    assert sim.lines is not None  # started with commands=True: its output is read
    return sim.lines


def _finish_service(service: Child, progress: Progress, by_itself: bool) -> int | None:
    """Let ``run --cycles N`` end by itself (``by_itself``); else, or if it does not, SIGTERM it. Its exit status."""
    if by_itself:
        try:
            return service.process.wait(timeout=SERVICE_EXIT_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            progress.note(f"the service did not end by itself within {SERVICE_EXIT_TIMEOUT_S:g} s of the last "
                          f"part; stopping it (SIGTERM)")
    service.process.send_signal(signal.SIGTERM)
    try:
        return service.process.wait(timeout=STOP_TIMEOUT_S)
    except subprocess.TimeoutExpired as exc:
        raise SimulateTimeout(f"the service did not stop within {STOP_TIMEOUT_S:g} s of SIGTERM; "
                              f"{service.log}: {service.tail()}") from exc
