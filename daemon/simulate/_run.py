"""One ``monoguide simulate`` run: the simulated cell and the service as two child processes, as on a line.

``monoguide sim-cell`` (the simulated PLC playing N parts, the robot controller with the part supply and
its truth log, the tracker) starts first; once it says where its devices listen, ``monoguide run --cycles
N`` starts against the same derived config (with ``--faults`` without ``--cycles``: it is stopped after the
last part). Progress comes from the line: the simulated PLC's record of every part it played (``plc:
{...}`` on sim-cell's standard output). With ``--faults`` each device and PLC
fault is sent to sim-cell's standard input in turn, between good cycles. The service's resident memory,
threads and open files are sampled from ``/proc`` while it runs (the last sample is "at the end").

Every wait has a deadline and says what it waited for; Ctrl-C or SIGTERM stops the service first, then the
cell. The children run in their own sessions, so a Ctrl-C on the terminal reaches only this process, which
stops them in that order.
"""

from __future__ import annotations

import contextlib
import json
import os
import queue
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

from monoguide.daemon.errors import SimulateChildEnded, SimulateTimeout
from monoguide.daemon.service import JOURNAL_FILE, Journal, JournalRow
from monoguide.daemon.simulate._config import DerivedCell, derive_config
from monoguide.daemon.simulate._summary import InjectedFault, read_truth_log
from monoguide.drivers.errors import ConfigError

CELL_START_TIMEOUT_S = 90.0  # building the cell and starting three device processes on a busy machine
SERVICE_START_TIMEOUT_S = 60.0  # service start + devices connected + first part finished
PART_TIMEOUT_S = 60.0  # no part finished for this long: something hangs
FAULT_PART_TIMEOUT_S = 90.0  # with --faults: the line waits up to 30 s for READY after a fault
SERVICE_EXIT_TIMEOUT_S = 15.0
STOP_TIMEOUT_S = 10.0
POLL_S = 0.1
GOOD_BEFORE_FAULTS = 1
_CODE_WORD = re.compile(r"\b[A-Z][A-Z0-9]*(?:_[A-Z0-9]+)+\b")

# device, fault, the error codes any of which reports it (journal rows, the line's view, the service's log)
FAULT_PLAN: tuple[tuple[str, str, tuple[str, ...]], ...] = (
    ("camera", "timeout", ("DEVICE_TIMEOUT",)),
    ("camera", "disconnect", ("DEVICE_DISCONNECTED", "DEVICE_NOT_FOUND")),
    ("camera", "black", ("LOW_CONTRAST", "HOLE_NOT_FOUND", "BAD_IMAGE", "FEATURE_NOT_FOUND")),
    ("camera", "occluded", ("HOLE_NOT_FOUND", "LOW_CONTRAST", "FEATURE_NOT_FOUND", "HOLE_AMBIGUOUS")),
    ("camera", "glare", ("IMAGE_SATURATED", "HOLE_NOT_FOUND", "HOLE_AMBIGUOUS", "RESIDUAL_TOO_LARGE",
                         "INCONSISTENT_MEASUREMENT", "FEATURE_NOT_FOUND")),
    ("robot", "protective-stop", ("ROBOT_PROTECTIVE_STOP",)),
    ("robot", "never-reach", ("ROBOT_POSITION_TIMEOUT",)),
    ("robot", "no-ack", ("ROBOT_ACK_TIMEOUT",)),
    ("robot", "stall", ("ROBOT_POSITION_TIMEOUT", "DEVICE_TIMEOUT", "ROBOT_ACK_TIMEOUT", "DEVICE_DISCONNECTED")),
    ("robot", "drop", ("DEVICE_DISCONNECTED", "ROBOT_NOT_READY", "DEVICE_TIMEOUT")),
    ("robot", "program-stopped", ("ROBOT_NOT_READY",)),
    ("plc", "trigger-dropped-early", ("PLC_TRIGGER_DROPPED",)),
    ("plc", "no-ack", ("PLC_ACK_TIMEOUT",)),
    ("plc", "heartbeat-stopped", ("PLC_HEARTBEAT_LOST", "CYCLE_ABORTED")),
)


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
    fault_names: tuple[str, ...] = ()  # "device name" of FAULT_PLAN to inject (empty: every one)
    calibration: Path | None = None  # the service runs with this file's calibration values (the cell: config's)


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


def fault_plan(names: tuple[str, ...] = ()) -> tuple[tuple[str, str, tuple[str, ...]], ...]:
    """The faults to inject: those of :data:`FAULT_PLAN` named ``"device name"`` (all when none are named)."""
    known = {f"{device} {name}": (device, name, codes) for device, name, codes in FAULT_PLAN}
    for wanted in names:
        if wanted not in known:
            raise ConfigError(f"--fault {wanted!r}: expected one of {', '.join(known)}")
    return tuple(known[n] for n in names) if names else FAULT_PLAN


def cycles_needed_for_faults(names: tuple[str, ...] = ()) -> int:
    """One good cycle first, then each fault followed by a good cycle."""
    return GOOD_BEFORE_FAULTS + 2 * len(fault_plan(names))


def run_simulation(options: RunOptions, progress: Progress | None = None) -> RunResult:
    """Run the cell and the service for ``options.cycles`` parts; see the module's doc."""
    progress = progress or Progress()
    started = time.monotonic()
    cell = derive_config(options.config, options.work_dir, seed=options.seed, robot=options.robot,
                         perfect_robot=options.perfect_robot, host=options.host, faults=options.faults,
                         calibration=options.calibration)
    cell.state_dir.mkdir(parents=True, exist_ok=True)
    logs = options.work_dir.resolve()
    sim_log, service_log = logs / "sim-cell.log", logs / "service.log"
    children = _Children()
    previous = signal.signal(signal.SIGTERM, _raise_interrupt)
    try:
        progress.note(f"starting the simulated cell on {cell.host} (config {cell.config})")
        sim = children.start("simulated cell", [
            sys.executable, "-m", "monoguide.daemon.cli", "sim-cell", "--config", str(cell.config), "--truth-log",
            str(cell.truth_log), "--parts", str(options.cycles)], sim_log, stdin=True)
        lines = _LineReader(sim.process.stdout)  # type: ignore[arg-type]
        _wait_listening(sim, lines, sim_log)
        # --cycles N: the service stops by itself after N cycles, as a line's test run would. With --faults a
        # part may end without a cycle (or with two), so the service runs until stopped after the last part.
        until = () if options.faults else ("--cycles", str(options.cycles))
        calibrated = f"; calibration of {options.calibration}, config {cell.service}" if cell.calibration else ""
        progress.note(f"starting the service: monoguide run {' '.join(until)} (state {cell.state_dir}{calibrated})")
        service = children.start("service", [
            sys.executable, "-m", "monoguide.daemon.cli", "run", "--config", str(cell.service), "--state-dir",
            str(cell.state_dir), *until], service_log)
        records, faults, samples = _play(options, cell, sim, service, lines, progress)
        service_exit = _finish_service(service, progress, by_itself=not options.faults)
        children.stop_all()
        rows = _journal_rows(cell.state_dir)
        return RunResult(cell, records, rows, read_truth_log(cell.truth_log, grasps=True), faults, samples,
                         _logged_codes(service_log), service_exit, time.monotonic() - started)
    finally:
        children.stop_all()
        signal.signal(signal.SIGTERM, previous)


def sample_process(pid: int) -> dict[str, float] | None:
    """Resident memory (MB, also its children's), threads and open files of process ``pid``; None when gone
    (or a zombie: no memory left to tell)."""
    fields = _status_fields(pid)
    try:
        fds = len(os.listdir(f"/proc/{pid}/fd"))
    except OSError:
        return None
    if fields is None or "VmRSS" not in fields or "Threads" not in fields:
        return None
    sample = {"t": time.monotonic(), "rss_mb": fields["VmRSS"] / 1024.0, "threads": fields["Threads"],
              "fds": float(fds), "children_rss_mb": 0.0}
    try:
        children = Path(f"/proc/{pid}/task/{pid}/children").read_text().split()
    except OSError:
        children = []
    for child in children:
        child_fields = _status_fields(int(child))
        if child_fields is not None:
            sample["children_rss_mb"] += child_fields.get("VmRSS", 0.0) / 1024.0
    return sample


def _status_fields(pid: int) -> dict[str, float] | None:
    """The numeric fields of ``/proc/<pid>/status`` (kB for the memory ones); None when the process is gone."""
    try:
        text = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return None
    fields = {}
    for line in text.splitlines():
        key, _, value = line.partition(":")
        words = value.split()
        if words and words[0].isdigit():
            fields[key] = float(words[0])
    return fields


# --- private ------------------------------------------------------------------------------------


# Runs in the child before it becomes ``argv``: asks Linux for SIGTERM when this process (the parent) dies,
# even by kill -9 (PR_SET_PDEATHSIG, kept across exec), then becomes the child. A parent gone before the
# request (the child was re-parented) ends the child at once. Not a preexec_fn: the parent has threads.
# Linux sends it when the *thread* that started the child ends: run_simulation starts and stops its children
# in the same call, so that thread outlives them.
_LAUNCHER = (
    "import ctypes, os, sys\n"
    "if sys.platform.startswith('linux'):\n"
    "    ctypes.CDLL(None, use_errno=True).prctl(1, 15, 0, 0, 0)\n"
    "if os.getppid() != int(sys.argv[1]):\n"
    "    sys.exit(143)\n"
    "os.execv(sys.argv[2], sys.argv[2:])\n"
)


def dies_with_us(argv: list[str]) -> list[str]:
    """``argv`` started through the launcher above, so that the child ends when this process ends."""
    return [sys.executable, "-c", _LAUNCHER, str(os.getpid()), *argv]


def _raise_interrupt(_signum: int, _frame: object) -> None:
    raise KeyboardInterrupt


class _Child:
    def __init__(self, name: str, process: subprocess.Popen[str], log: Path, log_file: IO[str]) -> None:
        self.name, self.process, self.log, self.log_file = name, process, log, log_file

    def tail(self, lines: int = 8) -> str:
        try:
            text = self.log.read_text(errors="replace").strip().splitlines()
        except OSError:
            return "(no log)"
        return " | ".join(text[-lines:]) or "(its log is empty)"

    def ended(self) -> int | None:
        return self.process.poll()


class _Children:
    """The run's child processes, stopped in reverse order of starting (the service before the cell)."""

    def __init__(self) -> None:
        self.started: list[_Child] = []

    def start(self, name: str, argv: list[str], log: Path, stdin: bool = False) -> _Child:
        log_file = log.open("w")
        process = subprocess.Popen(dies_with_us(argv), stdin=subprocess.PIPE if stdin else subprocess.DEVNULL,
                                   stdout=subprocess.PIPE if stdin else log_file, stderr=log_file, text=True,
                                   start_new_session=True)  # Ctrl-C reaches us only: we stop them in order
        child = _Child(name, process, log, log_file)
        self.started.append(child)
        return child

    def stop_all(self) -> None:
        while self.started:
            child = self.started.pop()
            process = child.process
            if process.stdin is not None:
                with contextlib.suppress(OSError):
                    process.stdin.close()
            if process.poll() is None:
                process.send_signal(signal.SIGTERM)
                try:
                    process.wait(timeout=STOP_TIMEOUT_S)
                except subprocess.TimeoutExpired:
                    print(f"simulate: the {child.name} (pid {process.pid}) did not stop within "
                          f"{STOP_TIMEOUT_S:g} s of SIGTERM; killing it", file=sys.stderr)
                    process.kill()
                    process.wait(timeout=STOP_TIMEOUT_S)
            with contextlib.suppress(OSError):  # what the child left behind in its own group (its session)
                os.killpg(process.pid, signal.SIGKILL)
            if process.stdout is not None:
                process.stdout.close()
            child.log_file.close()


class _LineReader:
    """Lines of a child's standard output, read by a thread into a queue (the pipe never fills up)."""

    def __init__(self, stream: IO[str]) -> None:
        self.queue: queue.Queue[str | None] = queue.Queue()
        self.seen: list[str] = []
        threading.Thread(target=self._read, args=(stream,), daemon=True).start()

    def _read(self, stream: IO[str]) -> None:
        with contextlib.suppress(ValueError, OSError):
            for line in stream:
                self.queue.put(line.rstrip("\n"))
        self.queue.put(None)

    def get(self, timeout_s: float) -> str | None:
        """The next line, ``""`` if none came within ``timeout_s``, None at the end of the stream."""
        try:
            line = self.queue.get(timeout=timeout_s)
        except queue.Empty:
            return ""
        if line is not None:
            self.seen.append(line)
        return line


def _wait_listening(sim: _Child, lines: _LineReader, log: Path) -> None:
    """Until sim-cell prints ``state file ...`` (it does once every device listens)."""
    deadline = time.monotonic() + CELL_START_TIMEOUT_S
    while time.monotonic() < deadline:
        line = lines.get(POLL_S)
        if line is None or sim.ended() is not None:
            raise SimulateChildEnded(f"the simulated cell ended (status {sim.process.wait()}) before its devices "
                                     f"listened; {log}: {sim.tail()}")
        if line.startswith("state file "):
            return
    raise SimulateTimeout(f"the simulated cell did not say its devices listen within {CELL_START_TIMEOUT_S:g} s; "
                          f"its output: {' | '.join(lines.seen[-5:]) or '(none)'}; {log}: {sim.tail()}")


def _play(options: RunOptions, cell: DerivedCell, sim: _Child, service: _Child, lines: _LineReader,
          progress: Progress) -> tuple[list[dict[str, Any]], list[InjectedFault], list[dict[str, float]]]:
    """Collect the line's records of ``options.cycles`` parts, injecting faults, sampling the service."""
    total = options.cycles
    records: list[dict[str, Any]] = []
    samples: list[dict[str, float]] = []
    schedule = _fault_schedule(total, fault_plan(options.fault_names)) if options.faults else {}
    injected: list[InjectedFault] = []
    pending_clear: tuple[str, float | None] | None = None  # (command, at monotonic time or None: after the part)
    part_timeout = FAULT_PART_TIMEOUT_S if options.faults else PART_TIMEOUT_S
    deadline = time.monotonic() + SERVICE_START_TIMEOUT_S + part_timeout
    service_gone_at: float | None = None
    heartbeat_s = float(cell.data["plc"].get("heartbeat_timeout_s", 2.0))
    while len(records) < total:
        now = time.monotonic()
        if pending_clear is not None and pending_clear[1] is not None and now >= pending_clear[1]:
            _command(sim, pending_clear[0])
            pending_clear = None
        if len(records) in schedule and not any(f.cycle == len(records) + 1 for f in injected):
            device, name, expected = schedule[len(records)]
            if pending_clear is not None:  # the previous fault ends before the next one starts
                _command(sim, pending_clear[0])
                pending_clear = None
            _command(sim, f"{device} {name}" + (" 1" if device == "camera" else ""))
            injected.append(InjectedFault(len(records) + 1, device, name, expected))
            progress.note(f"cycle {len(records) + 1}: injecting {device} {name}")
            if device == "plc" and name == "heartbeat-stopped":
                pending_clear = ("plc none", now + 2.5 * heartbeat_s)
            elif device != "camera":
                pending_clear = (f"{device} none", None)
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
            if pending_clear is not None and pending_clear[1] is None:
                _command(sim, pending_clear[0])
                pending_clear = None
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
    return records, injected, samples


def _fault_schedule(total: int, plan: tuple[tuple[str, str, tuple[str, ...]], ...]) -> dict[
        int, tuple[str, str, tuple[str, ...]]]:
    """Which fault to inject after how many finished parts: a good one first, then one every other part."""
    return {GOOD_BEFORE_FAULTS + 2 * k: fault for k, fault in enumerate(plan) if GOOD_BEFORE_FAULTS + 2 * k < total - 1}


def _command(sim: _Child, text: str) -> None:
    if sim.process.stdin is None:
        return
    try:
        sim.process.stdin.write(text + "\n")
        sim.process.stdin.flush()
    except OSError as exc:
        raise SimulateChildEnded(f"cannot send {text!r} to the simulated cell: {exc}; {sim.log}: {sim.tail()}") from exc


def _finish_service(service: _Child, progress: Progress, by_itself: bool) -> int | None:
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


def _journal_rows(state_dir: Path) -> list[JournalRow]:
    if not (state_dir / JOURNAL_FILE).exists():
        return []
    with Journal(state_dir) as journal:
        return list(reversed(journal.last_cycles(journal.cycle_counter() or 1)))


def _logged_codes(log: Path) -> set[str]:
    """Error codes the service named in its log (PLC-side faults that end no cycle are only logged)."""
    try:
        text = log.read_text(errors="replace")
    except OSError:
        return set()
    return set(_CODE_WORD.findall(text))

