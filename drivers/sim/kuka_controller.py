"""The simulated KUKA controller: the XML channel of ``config/kuka/`` (KUKA.Ethernet KRL) on a real TCP socket.

Run as ``python -m monoguide.drivers.sim.kuka_controller --spec ROBOT.json --truth TRUTH.json --host
127.0.0.60``. It prints ``LISTEN robot <host>:<port>`` and serves until SIGTERM/SIGINT or until its parent
goes away; with ``--commands`` each line of standard input is a command (a fault, ``robot_motion.FAULT_MODES`` or
``FAULT_ACTIONS``, or ``grasp``: the cell's go).

It behaves as EthernetKRL does for ``config/kuka/monoguide.xml`` (:class:`EkiBuffer`): one client at a time
(another connection is closed at once); every received element goes into a FIFO of its own and one flag says
that a ``<Sensor>`` message came, however many did; a REAL is read from a fixed-point decimal only (an exponent
form is a read that fails: the program answers -1); after the client disconnects the channel is closed
(connections are closed at once) until the robot program, once idle, has drained its buffer and called
``EKI_Open`` again; a program restart deletes the channel and the start opens a fresh one. The program reads
its buffer as ``config/kuka/monoguide.src`` does, oldest message first, an interpolation cycle after it came;
the report is the timer interrupt's: every ``REPORT_PERIOD_S`` (the first of a connection with ``<Identity>``)
and at once after an answer. A malformed or hostile message is logged and dropped, never obeyed.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import re
import sys
import time
from collections import deque
from pathlib import Path

from monoguide.drivers import kuka_protocol as kuka
from monoguide.drivers.errors import RobotMessageInvalid
from monoguide.drivers.robot import COMMAND_OFFSET
from monoguide.drivers.robot_program import REQUEST
from monoguide.drivers.sim import part_supply
from monoguide.drivers.sim.robot_motion import Request, SimRobotProgram
from monoguide.drivers.sim.robot_serve import (
    SimController,
    add_program_arguments,
    program_from_arguments,
    serve_controller,
)
from monoguide.solver.frames import T_to_kuka_frame, kuka_frame_to_T

log = logging.getLogger("monoguide.sim.kuka")

IDENTITY = ("KUKA", "KR 210 R2700 (simulated)", "SIM-KUKA-0001", "KSS 8.6")
REPORT_PERIOD_S = 0.02
TAKE_LATENCY_S = 0.012  # the program sees a message at its next interpolation cycle
BUFFER_LIMIT = 16  # <BUFFERING Limit="16"/> of config/kuka/monoguide.xml
ELEMENTS = tuple(signal.kuka for signal in REQUEST)  # Sensor/Request/@Seq ... Sensor/Offset/@C
INT_ELEMENTS = ELEMENTS[:3]
INT_TEXT = re.compile(r"[+-]?\d{1,10}")
REAL_TEXT = re.compile(r"[+-]?(\d+(\.\d*)?|\.\d+)")  # fixed point: no exponent, no inf, no nan


class EkiBuffer:
    """EKI's receive memory for the channel: a FIFO per configured element and one flag for the whole message
    (``Set_Flag`` of the root element). The program reads one message by taking the oldest of every element."""

    level = False

    def __init__(self) -> None:
        self.fifos: dict[str, deque[str]] = {tag: deque() for tag in ELEMENTS}
        self.flag = False

    def receive(self, message: bytes) -> int | None:
        """A message from the client into the FIFOs; returns its command (if it carries one), None when dropped."""
        try:
            root = kuka.parse(message, kuka.SENSOR_ROOT)
        except RobotMessageInvalid as exc:
            log.warning("dropped: %s", exc)
            return None
        if len(self.fifos[ELEMENTS[0]]) >= BUFFER_LIMIT:
            log.warning("buffer full (%d messages): dropped %r", BUFFER_LIMIT, message[:60])
            return None
        command = None
        for tag in ELEMENTS:
            path, _, attribute = tag.partition("/@")
            element = root.find(path.partition("/")[2])
            value = None if element is None else element.get(attribute)
            if value is not None:
                self.fifos[tag].append(value[:64])
                if tag == ELEMENTS[1] and INT_TEXT.fullmatch(value):
                    command = int(value)
        self.flag = True
        return command

    def clear(self) -> None:
        for fifo in self.fifos.values():
            fifo.clear()
        self.flag = False

    def next_request(self) -> Request | None:
        """The oldest message, every element read with its RET checked: a field that cannot be read makes it an
        unreadable request (``D_b`` None); FIFOs out of step (a message without every element) are all cleared."""
        while self.fifos[ELEMENTS[0]]:
            counts = {len(fifo) for fifo in self.fifos.values()}
            if len(counts) != 1:
                log.warning("element buffers out of step (%s): all cleared", sorted(counts))
                self.clear()
                return None
            texts = [self.fifos[tag].popleft() for tag in ELEMENTS]
            ints = [int(t) if INT_TEXT.fullmatch(t) else None for t in texts[:3]]
            reals = [float(t) if REAL_TEXT.fullmatch(t) else None for t in texts[3:]]
            if ints[0] is None or not -(2**31) <= ints[0] < 2**31:
                log.warning("a request whose Seq cannot be read (%r): not answered", texts[0])
                continue
            if None in ints or None in reals or any(abs(v) > 2**31 for v in ints):  # type: ignore[arg-type, operator]
                log.warning("request %d: a field cannot be read (%s)", ints[0], texts)
                return Request(ints[0], ints[1] or 0, ints[2] or 0, None, tuple(v or 0.0 for v in reals))
            frame = tuple(float(v) for v in reals)  # type: ignore[arg-type]
            return Request(ints[0], ints[1], ints[2], kuka_frame_to_T(*frame), frame)  # type: ignore[arg-type]
        return None


class KukaController(SimController):
    def __init__(self, program: SimRobotProgram, spec_path: Path, truth_path: Path) -> None:
        self.buffer = EkiBuffer()
        super().__init__(program, spec_path, truth_path, self.buffer)
        self.client: asyncio.StreamWriter | None = None
        self.channel_open = True  # EKI_Open called and not closed since
        self.lost = False  # the client went: the program reopens the channel once it is idle

    async def serve_client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        peer = writer.get_extra_info("peername")
        if self.client is not None or not self.channel_open or self.refusing:
            log.info("client %s refused (%s)", peer, "another client is connected" if self.client is not None else
                     "the channel is closed")
            writer.transport.abort()
            return
        self.client = writer
        log.info("client %s connected", peer)
        sender = asyncio.get_running_loop().create_task(self._send_reports(writer))
        framing = bytearray()
        try:
            while chunk := await reader.read(4096):
                if self.stalled:
                    continue
                framing.extend(chunk)
                try:
                    messages = kuka.split_messages(framing, kuka.SENSOR_ROOT)
                except RobotMessageInvalid as exc:
                    log.warning("dropped: %s", exc)
                    continue
                for message in messages:
                    if self.buffer.receive(message) == COMMAND_OFFSET:
                        self.offset_arrived()
                    asyncio.get_running_loop().call_later(TAKE_LATENCY_S, self.step)
        except ConnectionError:
            pass
        finally:
            sender.cancel()
            writer.close()
            if self.client is writer:
                self._disconnected()
            log.info("client %s disconnected", peer)

    def drop_all(self) -> None:
        if self.client is not None:
            self.client.transport.abort()
            self._disconnected()

    def after_step(self, changed: bool) -> None:
        p = self.program
        if self.lost and p.program_running and p.state == "IDLE" and not self.buffer.fifos[ELEMENTS[0]]:
            log.info("the program reopens the channel (EKI_Clear, EKI_Init, EKI_Open)")
            self.buffer.clear()
            self.lost = False
            self.channel_open = True

    def on_event(self, event: dict[str, object]) -> None:
        super().on_event(event)
        if event["event"] == "answer" and self.client is not None and not self.stalled:
            self.client.write(self.report(answer=event))  # the interrupt reports at once after an answer
        elif event["event"] == "stopped" and self.program.fault != "program-stopped":
            log.info("program reset: the channel is deleted")
            self.drop_all()
            self.channel_open = self.lost = False
            self.buffer.clear()
        elif event["event"] == "started":  # a start from the beginning: EKI_Init and EKI_Open of a fresh channel
            self.drop_all()
            self.buffer.clear()
            self.channel_open, self.lost = True, False

    def report(self, identity: bool = False, answer: dict[str, object] | None = None) -> bytes:
        """The <Robot> report: the program's handshake now, or as it was at ``answer`` (the interrupt the answer set
        off runs before the program's next statement)."""
        p = self.program
        hs = answer or {"ack_sequence": p.ack_sequence, "program_status": p.program_status,
                        "in_position": p.in_position, "held_sequence": p.held_sequence,
                        "offset_valid": p.offset_valid}
        return kuka.encode_report(kuka.KukaReport(
            mode="AUT" if p.safety == "NORMAL" else "T1", safety=p.safety, program_running=p.program_running,
            pos=T_to_kuka_frame(p.T_b_f_reported), ack_sequence=int(hs["ack_sequence"]),  # type: ignore[call-overload]
            in_position=int(hs["in_position"]), program_status=int(hs["program_status"]),  # type: ignore[call-overload]
            ipoc=int(self.now() * 1000), identity=IDENTITY if identity else None,
            held_sequence=int(hs["held_sequence"]), offset_valid=bool(hs["offset_valid"])))  # type: ignore[call-overload]

    # --- private ------------------------------------------------------------------------------

    def _disconnected(self) -> None:
        self.client = None
        if self.channel_open:
            self.channel_open = False  # only EKI_Open serves again
            self.lost = True

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
    add_program_arguments(parser)
    part_supply.add_arguments(parser)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, stream=sys.stderr, format="sim-kuka: %(message)s")
    controller = KukaController(program_from_arguments(args), args.spec, args.truth)
    return asyncio.run(serve_controller(controller, controller.serve_client, args.host, args.port, args.commands))


if __name__ == "__main__":
    sys.exit(main())
