"""The simulated KUKA controller: the XML channel of ``config/kuka/`` (EKI style) on a real TCP socket.

Run as ``python -m monoguide.drivers.sim.kuka_controller --spec ROBOT.json --truth TRUTH.json --host
127.0.0.60``. It prints ``LISTEN robot <host>:<port>`` and serves until SIGTERM/SIGINT or until its parent
goes away; with ``--commands`` each line of standard input is a fault (``robot_motion.FAULT_MODES``).
Each client gets a ``<Robot>`` report every ``REPORT_PERIOD_S`` (the first with ``<Identity>``) and one
right after each request it takes; ``<Sensor>`` requests feed :class:`SimRobotProgram`, as the KRL program
``config/kuka/monoguide.src`` would. A malformed or hostile message is logged and dropped, never obeyed; the
connection stays.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import sys
import time
from pathlib import Path

import numpy as np

from monoguide.drivers import kuka_protocol as kuka
from monoguide.drivers.errors import RobotMessageInvalid
from monoguide.drivers.sim import part_supply
from monoguide.drivers.sim.robot_motion import (
    FAULT_MODES,
    SimRobotProgram,
    apply_command,
    load_robot_spec,
    run_program,
    serve_controller,
)
from monoguide.solver.frames import T_to_kuka_frame, kuka_frame_to_T

log = logging.getLogger("monoguide.sim.kuka")

IDENTITY = ("KUKA", "KR 210 R2700 (simulated)", "SIM-KUKA-0001", "KSS 8.6")
REPORT_PERIOD_S = 0.02


class KukaController:
    def __init__(self, program: SimRobotProgram, spec_path: Path, truth_path: Path) -> None:
        self.program = program
        self.spec_path = spec_path
        self.truth_path = truth_path
        self.writers: set[asyncio.StreamWriter] = set()
        self.t0 = time.monotonic()
        self.stalled = False

    def now(self) -> float:
        return time.monotonic() - self.t0

    async def serve_client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        peer = writer.get_extra_info("peername")
        self.writers.add(writer)
        log.info("client %s connected", peer)
        sender = asyncio.get_running_loop().create_task(self._send_reports(writer))
        buffer = bytearray()
        try:
            while chunk := await reader.read(4096):
                if self.stalled:
                    continue
                buffer.extend(chunk)
                try:
                    messages = kuka.split_messages(buffer, kuka.SENSOR_ROOT)
                except RobotMessageInvalid as exc:
                    log.warning("dropped: %s", exc)
                    continue
                for message in messages:
                    self._take(message, writer)
        except ConnectionError:
            pass
        finally:
            sender.cancel()
            self.writers.discard(writer)
            writer.close()
            log.info("client %s disconnected", peer)

    async def run_program(self, stop: asyncio.Event) -> None:
        await run_program(self.program, self.spec_path, self.truth_path, self.now, lambda: self.stalled, stop)

    def drop_all(self) -> None:
        for writer in list(self.writers):
            writer.transport.abort()
        self.writers.clear()

    def command(self, text: str) -> None:
        """A fault command at run time (``none`` clears): a stall ends at once, the reports flow again."""
        if apply_command(self.program, self.truth_path, text) and self.stalled:
            log.info("stall ends: the controller answers again")
            self.stalled = False

    def report(self, identity: bool = False) -> bytes:
        p = self.program
        return kuka.encode_report(kuka.KukaReport(
            mode="AUT" if p.safety == "NORMAL" else "T1", safety=p.safety, program_running=p.program_running,
            pos=T_to_kuka_frame(p.T_b_f_reported), ack_sequence=p.ack_sequence, in_position=p.in_position,
            program_status=p.program_status, ipoc=int(self.now() * 1000), identity=IDENTITY if identity else None))

    # --- private ------------------------------------------------------------------------------

    def _take(self, message: bytes, writer: asyncio.StreamWriter) -> None:
        try:
            request = kuka.decode_request(message)
        except RobotMessageInvalid as exc:
            log.warning("dropped: %s", exc)
            return
        D_b = kuka_frame_to_T(*request.offset)
        new = self.program.handle(request.sequence, request.command, request.pose_number, D_b, request.offset,
                                  self.now())
        if new and self.program.faulted and self.program.fault in ("stall", "drop"):
            log.info("fault %s", self.program.fault)
            if self.program.fault == "stall":
                self.stalled = True
            else:
                asyncio.get_running_loop().call_soon(self.drop_all)
            return
        writer.write(self.report())

    async def _send_reports(self, writer: asyncio.StreamWriter) -> None:
        writer.write(self.report(identity=True))
        next_time = time.monotonic()
        while not writer.is_closing():
            next_time += REPORT_PERIOD_S
            await asyncio.sleep(max(0.0, next_time - time.monotonic()))
            if not self.stalled:
                writer.write(self.report())


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``python -m monoguide.drivers.sim.kuka_controller``."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spec", type=Path, required=True, help="robot spec (SimCell.write_robot_spec)")
    parser.add_argument("--truth", type=Path, required=True, help="where to write what the robot did")
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, default=kuka.DEFAULT_PORT)
    parser.add_argument("--move-time", type=float, default=0.5, help="seconds per move to a measuring pose")
    parser.add_argument("--fault", default="none", choices=FAULT_MODES)
    parser.add_argument("--seed", type=int, default=None)
    parser.add_argument("--commands", action="store_true",
                        help="read fault commands from standard input, one per line (none clears)")
    part_supply.add_arguments(parser)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, stream=sys.stderr, format="sim-kuka: %(message)s")
    spec = load_robot_spec(args.spec)
    program = SimRobotProgram(spec, np.random.default_rng(spec.seed + 3 if args.seed is None else args.seed),
                              args.move_time, args.fault, supply=part_supply.from_arguments(args))
    controller = KukaController(program, args.spec, args.truth)
    return asyncio.run(serve_controller(controller.serve_client, args.host, args.port, controller.run_program,
                                        controller.drop_all, controller.command if args.commands else None))


if __name__ == "__main__":
    sys.exit(main())
