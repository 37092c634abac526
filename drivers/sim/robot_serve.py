"""What the simulated UR and KUKA controllers share around the robot program: its loop, the truth file, the
fault commands on standard input, the grasp go, the cut of every connection after an offset, serving until stopped.

A controller (:class:`SimController`) runs :class:`~monoguide.drivers.sim.robot_motion.SimRobotProgram` in
:meth:`SimController.step`: once a period (the motion) and at once when a request arrives (the program polls its
inputs every few ms), each step and the truth file written in one synchronous call. Standard input (with
``--commands``) carries one line per command: a fault (``robot_motion.FAULT_MODES``, ``FAULT_ACTIONS``) or
``grasp`` (the cell's go, which ``monoguide sim-cell`` forwards from the simulated PLC); ``none`` clears the mode
in force and every one-shot fault still armed or under way (a cut due or in progress). Each grasp the program
runs or refuses is printed on standard output as ``GRASP {json}`` (sim-cell passes it back to the PLC and into its
own output).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import logging
import os
import signal
import sys
import threading
import time
from pathlib import Path

import numpy as np

from monoguide.drivers.sim import part_supply
from monoguide.drivers.sim.robot_motion import (
    FaultCommand,
    RequestSource,
    SimRobotProgram,
    file_mtime,
    load_robot_spec,
    parse_fault,
    write_truth,
)

log = logging.getLogger("monoguide.sim.robot")

GRASP_COMMAND = "grasp"
PERIOD_S = 0.02


class SimController:
    """The controller around the program. A make supplies ``source`` (where the program reads requests),
    :meth:`drop_all`, :meth:`after_step` (what it sends then) and its connections."""

    def __init__(self, program: SimRobotProgram, spec_path: Path, truth_path: Path, source: RequestSource) -> None:
        self.program = program
        self.spec_path = spec_path
        self.truth_path = truth_path
        self.source = source
        self.t0 = time.monotonic()
        self.stalled = False
        self.refuse_until = 0.0  # a cut: new connections are closed at once until then (time.monotonic())
        self._cut_timer: asyncio.TimerHandle | None = None  # a cut due MS ms after its offset arrived

    def now(self) -> float:
        return time.monotonic() - self.t0

    @property
    def refusing(self) -> bool:
        return time.monotonic() < self.refuse_until

    def step(self) -> None:
        """One pass of the program's loop; the truth file says what it did before anything can be sent."""
        if self.stalled:
            return
        taken = self.program.requests
        changed = self.program.step(self.now(), self.source)
        if changed:
            write_truth(self.truth_path, self.program.truth())
        for event in self.program.take_events():
            self.on_event(event)
        if self.program.requests > taken and self.program.fault in ("stall", "drop"):
            self.enter_fault(self.program.fault)
        self.after_step(changed)

    def offset_arrived(self) -> None:
        """An offset request reached the controller: a cut-after-offset armed now takes effect (MS ms later)."""
        cut = self.program.take_cut()
        if cut is None:
            return
        log.info("cut-after-offset: every connection closes in %g ms, for %g s", cut.after_ms, cut.down_s)
        if cut.after_ms <= 0:
            self._cut(cut)  # now: before the program has even seen the request, nothing of its answer can go out
        else:
            self._cut_timer = asyncio.get_running_loop().call_later(cut.after_ms / 1000.0, self._cut, cut)

    def command(self, text: str) -> None:
        """A line of standard input: ``grasp`` (the go) or a fault (``none`` clears); a bad one is said on stderr."""
        if text == GRASP_COMMAND:
            if self.stalled:
                log.info("grasp go not seen: the controller is stalled")
                return
            self.program.go()
            self.step()
            return
        try:
            fault = parse_fault(text)
        except ValueError as exc:
            print(f"error: {exc}", file=sys.stderr, flush=True)
            return
        self.program.command(fault, self.now())
        if fault.name == "none":
            self._end_cut()
        elif fault.name == "cut":
            self._cut(fault)
        write_truth(self.truth_path, self.program.truth())  # the fault in force, even while stalled (tests wait)
        if fault.name != "stall" and self.stalled:
            log.info("stall ends: the controller answers again")
            self.stalled = False
            self.resume()
        self.step()

    def enter_fault(self, fault: str) -> None:
        if fault == "stall":
            log.info("fault stall: the controller freezes")
            self.stalled = True
            self.freeze()
        else:
            log.info("fault drop: closing every connection")
            asyncio.get_running_loop().call_soon(self.drop_all)

    async def run(self, stop: asyncio.Event) -> None:
        """The program's loop: re-read the spec when it changes (a new part), step, write the truth file; nothing
        moves while the controller is stalled."""
        spec_mtime = file_mtime(self.spec_path)
        while not stop.is_set():
            if (mtime := file_mtime(self.spec_path)) != spec_mtime:
                spec_mtime = mtime
                try:
                    self.program.reload(load_robot_spec(self.spec_path))
                except (OSError, ValueError, KeyError) as exc:
                    log.warning("keeping the old spec, cannot re-read %s: %s", self.spec_path, exc)
            if not self.stalled:  # one synchronous step: the truth is on disk before any task sends the new state
                self.step()
                write_truth(self.truth_path, self.program.truth())
            with contextlib.suppress(asyncio.TimeoutError):
                await asyncio.wait_for(stop.wait(), PERIOD_S)
        if self.program.supply is not None:  # the controller stops: the part in the cell leaves
            self.program.supply.close()

    def on_event(self, event: dict[str, object]) -> None:
        if event["event"] == "grasp":
            print("GRASP " + json.dumps({k: v for k, v in event.items() if k != "event"}), flush=True)

    # --- what a make supplies -----------------------------------------------------------------------

    def drop_all(self) -> None:
        raise NotImplementedError

    def after_step(self, changed: bool) -> None:
        """After a step (KUKA: the report the timer interrupt sends at once after an answer)."""

    def freeze(self) -> None:
        """A stall begins: stop sending."""

    def resume(self) -> None:
        """A stall ends: send again."""

    # --- private ----------------------------------------------------------------------------------

    def _end_cut(self) -> None:
        """``none``: a cut due is not made, a cut under way ends (the cable is back in)."""
        if self._cut_timer is not None:
            self._cut_timer.cancel()
            self._cut_timer = None
            log.info("none: the cut due is not made")
        if self.refusing:
            log.info("none: the cut ends; connections are taken again")
        self.refuse_until = 0.0

    def _cut(self, cut: FaultCommand) -> None:
        self._cut_timer = None
        log.info("cut: every connection closed; new ones closed at once for %g s", cut.down_s)
        self.refuse_until = time.monotonic() + cut.down_s
        self.drop_all()


async def serve_controller(controller: SimController, client_handler: object, host: str, port: int,
                           commands: bool) -> int:
    """Listen on ``host:port``, print ``LISTEN robot host:port``, run the program loop, until SIGTERM/SIGINT or
    until the parent process is gone; then close every connection. ``commands``: each line of standard input is a
    command (:meth:`SimController.command`); the end of the input is fine."""
    # noted before LISTEN is printed: the parent may act on that line and die at once (a test killing a
    # sim-cell), and a parent noted after its death would be init's pid, never gone: an orphan for good
    parent = os.getppid()
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for s in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(s, stop.set)
    server = await asyncio.start_server(client_handler, host, port, reuse_address=True)  # type: ignore[arg-type]
    write_truth(controller.truth_path, controller.program.truth())  # there before anyone can ask
    print(f"LISTEN robot {host}:{port}", flush=True)
    task = loop.create_task(controller.run(stop))
    if commands:
        threading.Thread(target=_read_commands, args=(loop, controller.command), daemon=True).start()
    while not stop.is_set() and os.getppid() == parent:
        with contextlib.suppress(asyncio.TimeoutError):
            await asyncio.wait_for(stop.wait(), 0.2)
    stop.set()
    server.close()
    controller.drop_all()
    await task
    return 0


def add_program_arguments(parser: argparse.ArgumentParser) -> None:
    """The robot program's options, the same for both controllers."""
    parser.add_argument("--move-time", type=float, default=0.5, help="seconds per move to a measuring pose")
    parser.add_argument("--grasp-time", type=float, default=0.1, help="seconds a grasp takes")
    parser.add_argument("--fault", default="none", type=_fault,
                        help="a fault from the start (robot_motion.FAULT_MODES, FAULT_ACTIONS; cut-after-offset MS "
                             "[DOWN_S])")
    parser.add_argument("--seed", type=int, default=None)
    parser.add_argument("--commands", action="store_true",
                        help="read commands from standard input, one per line: a fault (none clears) or grasp")


def program_from_arguments(args: argparse.Namespace) -> SimRobotProgram:
    spec = load_robot_spec(args.spec)
    return SimRobotProgram(spec, np.random.default_rng(spec.seed + 3 if args.seed is None else args.seed),
                           args.move_time, args.fault, supply=part_supply.from_arguments(args),
                           grasp_time_s=args.grasp_time)


def _fault(text: str) -> str:
    try:
        parse_fault(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from exc
    return text


def _read_commands(loop: asyncio.AbstractEventLoop, command: object) -> None:
    """Standard input, one command a line, each handed to the event loop (a thread: reading blocks)."""
    for text in sys.stdin:
        if text.strip():
            loop.call_soon_threadsafe(command, text.strip())  # type: ignore[arg-type]
