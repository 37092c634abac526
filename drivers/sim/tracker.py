"""The simulated laser tracker: a program behind a pseudo-terminal speaking ``docs/tracker-protocol.md``.

Run as ``python -m monoguide.drivers.sim.tracker --targets TARGETS.json``. It opens a pty, prints
``LISTEN tracker <slave path>`` on stdout and answers requests until SIGTERM/SIGINT or until its parent
goes away. The targets file (written by :meth:`monoguide.drivers.sim.cell.SimCell.write_tracker_targets`)
holds the true SMR centres in the tracker's frame; it is re-read when it changes, so the cell's truth
can move (a new part, the robot at another pose). Each measurement adds the tracker's noise. When the
targets file has a ``flange`` entry (the SMR on the robot's flange tool: its nest name, the simulated robot
controller's truth file, the robot base in the tracker's frame ``T_tracker_b`` and the SMR's offset ``smr_f``
on the flange) that nest is where the robot stands at the moment of the measurement.

Faults on command (simulator-only request ``SIM:FAULT <mode> [<count>] [<delay_s>]``, or ``--fault``):
``NOREPLY`` (silence), ``GARBAGE`` (a line that is not the protocol), ``BEAM`` (E200 beam broken),
``LATE`` (the reply comes ``delay_s`` late), ``NONE``. ``count`` requests are affected (0: until cleared).
"""

from __future__ import annotations

import argparse
import heapq
import json
import logging
import math
import os
import select
import signal
import sys
import time
import tty
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from monoguide.drivers.errors import DeviceProtocolError
from monoguide.drivers.sim.cell import TARGETS_FORMAT
from monoguide.drivers.tracker_protocol import (
    CMD_GET_UNIT,
    CMD_IDENTIFY,
    CMD_LIST_NESTS,
    CMD_MEASURE_POINT,
    CMD_SET_UNIT,
    CMD_SIM_FAULT,
    E_BAD_ARGUMENT,
    E_BEAM_BROKEN,
    E_MALFORMED,
    E_UNKNOWN_COMMAND,
    E_UNKNOWN_NEST,
    MAX_LINE_BYTES,
    UNIT_TO_MM,
    Request,
    decode_request,
    encode_error,
    encode_ok,
    format_measurement,
)

log = logging.getLogger("monoguide.sim.tracker")

IDENTITY = "monoguide,SimTracker,SIM-0001,1.0"
FAULT_MODES = ("NONE", "NOREPLY", "GARBAGE", "BEAM", "LATE")
SAMPLES_PER_POINT = 10
GARBAGE_LINE = b"\x15?#\xfe garbled \x00\x07\n"


@dataclass
class TrackerState:
    """What the simulated tracker knows: the true nest positions (tracker frame, mm) and its settings."""

    nests: dict[str, np.ndarray]
    noise_mm: float
    rng: np.random.Generator
    beam_on: str | None = None
    unit: str = "MM"
    measurement_number: int = 0
    fault: str = "NONE"
    fault_count: int = 0
    late_delay_s: float = 3.0
    scheduled: list[tuple[float, int, bytes]] = field(default_factory=list)  # (due, order, reply): a heap
    replies_scheduled: int = 0  # each reply's order, so that two due at once never compare their bytes
    flange: FlangeSmr | None = None


@dataclass(frozen=True)
class FlangeSmr:
    """The SMR on the robot's flange: nest ``nest`` is ``T_tracker_b · T_b_f · smr_f`` with the flange pose
    ``T_b_f`` read from the simulated controller's truth file ``truth`` when measured."""

    nest: str
    truth: Path
    T_tracker_b: np.ndarray
    smr_f: np.ndarray

    def position(self) -> np.ndarray:
        T_b_f = np.asarray(json.loads(self.truth.read_text())["T_b_f"], dtype=float)
        return (self.T_tracker_b @ T_b_f @ np.append(self.smr_f, 1.0))[:3]


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``python -m monoguide.drivers.sim.tracker``."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--targets", type=Path, required=True, help="JSON file with the true nest positions")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--fault", default="NONE", choices=FAULT_MODES)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, stream=sys.stderr, format="sim-tracker: %(message)s")

    nests, noise_mm, beam_on = load_targets(args.targets)
    state = TrackerState(nests, noise_mm, np.random.default_rng(args.seed), beam_on, fault=args.fault,
                         flange=load_flange(args.targets))
    master, slave = os.openpty()
    tty.setraw(slave)  # no echo, no line editing: bytes pass as sent
    # a client that stops reading must not block the simulator (and its SIGTERM) in os.write
    os.set_blocking(master, False)
    stop = _install_stop_handlers()
    # noted before LISTEN: a parent that acts on that line and dies at once must still be seen to be gone
    parent = os.getppid()
    print(f"LISTEN tracker {os.ttyname(slave)}", flush=True)
    serve(master, state, args.targets, stop, parent)
    os.close(master)
    os.close(slave)
    return 0


def serve(master: int, state: TrackerState, targets_path: Path, stop: list[bool], parent: int | None = None) -> None:
    """Answer requests on the pty ``master`` until ``stop[0]`` or until the ``parent`` process (default: the
    current parent) ends."""
    parent = os.getppid() if parent is None else parent
    seen = [_mtime(targets_path)]
    buffer = bytearray()
    while not stop[0] and os.getppid() == parent:
        _reload_if_changed(state, targets_path, seen)
        wait = 0.2 if not state.scheduled else max(0.0, min(0.2, state.scheduled[0][0] - time.monotonic()))
        try:
            readable, _, _ = select.select([master], [], [], wait)
        except InterruptedError:
            continue
        if readable:
            try:
                buffer.extend(os.read(master, 4096))
            except OSError:  # no client has the slave open: nothing to read
                time.sleep(0.05)
        if b"\n" in buffer:  # the truth as it is now: a file rewritten just before this request counts
            _reload_if_changed(state, targets_path, seen)
        while (end := buffer.find(b"\n")) >= 0:
            line = bytes(buffer[:end]).rstrip(b"\r")
            del buffer[: end + 1]
            _schedule(state, answer(state, line))
        if len(buffer) > MAX_LINE_BYTES:
            buffer.clear()
            _schedule(state, (0.0, encode_error(0, E_MALFORMED, "line too long")))
        now = time.monotonic()
        while state.scheduled and state.scheduled[0][0] <= now:
            _, _, reply = heapq.heappop(state.scheduled)
            try:
                os.write(master, reply)
            except BlockingIOError:
                log.warning("client is not reading; reply dropped: %r", reply)


def answer(state: TrackerState, line: bytes) -> tuple[float, bytes] | None:
    """The reply to one request line and its delay in seconds, or ``None`` for silence."""
    if not line.strip():
        return None
    try:
        request = decode_request(line)
    except DeviceProtocolError as exc:
        return 0.0, encode_error(0, E_MALFORMED, str(exc)[:80])
    if request.command == CMD_SIM_FAULT:
        return 0.0, _set_fault(state, request)
    fault = state.fault
    if fault != "NONE":
        state.fault_count -= 1
        if state.fault_count == 0:
            state.fault = "NONE"
    if fault == "NOREPLY":
        return None
    if fault == "GARBAGE":
        return 0.0, GARBAGE_LINE
    if fault == "BEAM" and request.command == CMD_MEASURE_POINT:
        return 0.0, encode_error(request.tag, E_BEAM_BROKEN, "beam broken: no target locked")
    delay = state.late_delay_s if fault == "LATE" else 0.0
    return delay, _execute(state, request)


def load_targets(path: Path) -> tuple[dict[str, np.ndarray], float, str | None]:
    """Read a targets file: ``{"format", "noise_mm", "nests": {name: [x, y, z]}, "beam_on"}``."""
    data = json.loads(Path(path).read_text())
    if data.get("format") != TARGETS_FORMAT:
        raise ValueError(f"{path}: format must be {TARGETS_FORMAT!r}, got {data.get('format')!r}")
    nests = {str(k): np.asarray(v, dtype=float).reshape(3) for k, v in data["nests"].items()}
    return nests, float(data["noise_mm"]), data.get("beam_on")


def load_flange(path: Path) -> FlangeSmr | None:
    """The targets file's ``flange`` entry (the SMR on the flange follows the robot), None when it has none."""
    flange = json.loads(Path(path).read_text()).get("flange")
    if not flange:
        return None
    return FlangeSmr(str(flange["nest"]), Path(flange["truth"]), np.asarray(flange["T_tracker_b"], dtype=float),
                     np.asarray(flange["smr_f"], dtype=float).reshape(3))


# --- private -----------------------------------------------------------------------------------


def _execute(state: TrackerState, request: Request) -> bytes:
    tag, command, args = request.tag, request.command, request.args
    if command == CMD_IDENTIFY:
        return encode_ok(tag, IDENTITY)
    if command == CMD_GET_UNIT:
        return encode_ok(tag, state.unit)
    if command == CMD_SET_UNIT:
        if len(args) != 1 or args[0].upper() not in UNIT_TO_MM:
            return encode_error(tag, E_BAD_ARGUMENT, f"unit must be one of {','.join(UNIT_TO_MM)}")
        state.unit = args[0].upper()
        return encode_ok(tag, state.unit)
    if command == CMD_LIST_NESTS:
        return encode_ok(tag, ",".join([*state.nests, *([state.flange.nest] if state.flange else [])]))
    if command == CMD_MEASURE_POINT:
        return _measure(state, tag, args)
    return encode_error(tag, E_UNKNOWN_COMMAND, f"unknown command {command}")


def _measure(state: TrackerState, tag: int, args: tuple[str, ...]) -> bytes:
    if len(args) > 1:
        return encode_error(tag, E_BAD_ARGUMENT, "at most one nest name")
    nest = args[0] if args else state.beam_on
    if nest is None:
        return encode_error(tag, E_BEAM_BROKEN, "beam broken: no target locked")
    if state.flange is not None and nest == state.flange.nest:
        try:
            true_point = state.flange.position()
        except (OSError, ValueError, KeyError) as exc:  # no robot truth (yet): nothing on the flange to lock on
            return encode_error(tag, E_BEAM_BROKEN, f"beam broken: flange SMR not found ({exc})"[:80])
    elif nest not in state.nests:
        return encode_error(tag, E_UNKNOWN_NEST, f"unknown nest {nest}")
    else:
        true_point = state.nests[nest]
    state.beam_on = nest
    # The spec's uncertainty is the 3-D RMS error of a point: per axis noise_mm / sqrt(3) for the mean of
    # SAMPLES_PER_POINT samples; the reported RMS is the samples' scatter about their mean.
    sigma_sample = state.noise_mm / math.sqrt(3.0) * math.sqrt(SAMPLES_PER_POINT)
    samples = true_point + state.rng.normal(0.0, sigma_sample, size=(SAMPLES_PER_POINT, 3))
    point = samples.mean(axis=0)
    rms = float(np.sqrt(np.mean(np.sum((samples - point) ** 2, axis=1))))
    state.measurement_number += 1
    return encode_ok(tag, *format_measurement(point, rms, state.measurement_number, state.unit))


def _set_fault(state: TrackerState, request: Request) -> bytes:
    args = request.args
    if not args or args[0].upper() not in FAULT_MODES:
        return encode_error(request.tag, E_BAD_ARGUMENT, f"mode must be one of {','.join(FAULT_MODES)}")
    try:
        count = int(args[1]) if len(args) > 1 else 1
        delay = float(args[2]) if len(args) > 2 else state.late_delay_s
    except ValueError:
        return encode_error(request.tag, E_BAD_ARGUMENT, "count must be an integer, delay a number")
    state.fault, state.fault_count, state.late_delay_s = args[0].upper(), count, delay
    log.info("fault %s for %s request(s)", state.fault, count or "all")
    return encode_ok(request.tag, state.fault, str(count))


def _schedule(state: TrackerState, reply: tuple[float, bytes] | None) -> None:
    if reply is not None:
        state.replies_scheduled += 1
        heapq.heappush(state.scheduled, (time.monotonic() + reply[0], state.replies_scheduled, reply[1]))


def _reload_if_changed(state: TrackerState, targets_path: Path, seen: list[tuple[int, int, int]]) -> None:
    if (now := _mtime(targets_path)) == seen[0]:
        return
    seen[0] = now
    try:
        state.nests, state.noise_mm, state.beam_on = load_targets(targets_path)
        state.flange = load_flange(targets_path)
    except (OSError, ValueError) as exc:
        log.warning("keeping old targets, cannot re-read %s: %s", targets_path, exc)


def _mtime(path: Path) -> tuple[int, int, int]:
    """What changes when the file is rewritten (atomically: a new inode), even within one clock tick."""
    try:
        st = path.stat()
    except OSError:
        return (-1, -1, -1)
    return (st.st_ino, st.st_mtime_ns, st.st_size)


def _install_stop_handlers() -> list[bool]:
    stop = [False]

    def _stop(signum: int, _frame: object) -> None:
        stop[0] = True

    signal.signal(signal.SIGTERM, _stop)
    signal.signal(signal.SIGINT, _stop)
    return stop


if __name__ == "__main__":
    sys.exit(main())
