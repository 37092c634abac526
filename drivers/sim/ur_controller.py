"""The simulated UR controller: an RTDE server (protocol version 2) that the genuine ur_rtde client accepts.

Run as ``python -m monoguide.drivers.sim.ur_controller --spec ROBOT.json --truth TRUTH.json --host
127.0.0.50``. It prints ``LISTEN robot <host>:<port>`` on stdout and serves until SIGTERM/SIGINT or until its
parent goes away; with ``--commands`` each line of standard input is a command (a fault,
``robot_motion.FAULT_MODES``, or ``grasp``: the cell's go). Like a real controller it answers the protocol and
controller version, output recipes (``NOT_FOUND`` for variables it does not know) and input recipes (``IN_USE`` for
registers another client holds), start and pause, and sends data packages at each recipe's frequency. The input
registers are the controller's: they keep their values when a client goes and when the robot program restarts.
The robot program's part — moving, in position, storing an offset, the grasp interlock, the grasp error — is
:class:`SimRobotProgram`, which reads the input registers as ``config/ur/monoguide.script`` polls them and
answers in the output registers 36-40 (``runtime_state`` PLAYING while it runs).
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from monoguide.drivers import rtde_protocol as rtde
from monoguide.drivers.errors import RobotMessageInvalid
from monoguide.drivers.robot import COMMAND_OFFSET
from monoguide.drivers.sim import part_supply
from monoguide.drivers.sim.robot_motion import Request, SimRobotProgram
from monoguide.drivers.sim.robot_serve import (
    SimController,
    add_program_arguments,
    program_from_arguments,
    serve_controller,
)
from monoguide.solver.frames import T_to_ur_pose, ur_pose_to_T

log = logging.getLogger("monoguide.sim.ur")

CONTROLLER_VERSION = (5, 15, 0, 0)
MAX_FREQUENCY_HZ = 500.0
ROBOT_MODE_RUNNING = 7
SAFETY_NORMAL, SAFETY_PROTECTIVE_STOP = 1, 3
RUNTIME_STOPPED, RUNTIME_PLAYING = 1, 2
TICK_S = 0.004
OUTPUT_TYPES: dict[str, str] = {
    "timestamp": "DOUBLE", "actual_TCP_pose": "VECTOR6D", "target_TCP_pose": "VECTOR6D",
    "actual_TCP_speed": "VECTOR6D", "actual_q": "VECTOR6D", "target_q": "VECTOR6D", "robot_mode": "INT32",
    "safety_mode": "INT32", "runtime_state": "UINT32", "robot_status_bits": "UINT32",
    "safety_status_bits": "UINT32", "speed_scaling": "DOUBLE", "target_speed_fraction": "DOUBLE",
    "actual_digital_input_bits": "UINT64", "actual_digital_output_bits": "UINT64",
    **{f"output_int_register_{k}": "INT32" for k in range(48)},
    **{f"output_double_register_{k}": "DOUBLE" for k in range(48)},
}
INPUT_TYPES: dict[str, str] = {
    **{f"input_int_register_{k}": "INT32" for k in range(48)},
    **{f"input_double_register_{k}": "DOUBLE" for k in range(48)},
}


@dataclass
class Recipe:
    recipe_id: int
    names: list[str]
    types: list[str]
    frequency_hz: float = 0.0


@dataclass(eq=False)  # identity: one object per connection, kept in sets
class Client:
    """One RTDE connection and what it set up."""

    writer: asyncio.StreamWriter
    peer: str
    protocol_version: int = 1
    outputs: Recipe | None = None
    inputs: dict[int, Recipe] = field(default_factory=dict)
    started: bool = False
    sender: asyncio.Task[None] | None = None


class RegisterSource:
    """The input registers as the URScript program reads them: the request they hold now (the same until the daemon
    writes another)."""

    level = True

    def __init__(self, inputs: dict[str, float]) -> None:
        self.inputs = inputs

    def next_request(self) -> Request | None:
        if not all(n in self.inputs for n in rtde.INPUT_RECIPE):
            return None  # no client has written the recipe yet: the registers read 0
        request = rtde.decode_request([self.inputs[n] for n in rtde.INPUT_RECIPE])
        return Request(request.sequence, request.command, request.pose_number,
                       ur_pose_to_T(np.array(request.offset_ur)), request.offset_ur)


class UrController(SimController):
    """The controller: clients, the register bank and the robot program."""

    def __init__(self, program: SimRobotProgram, spec_path: Path, truth_path: Path) -> None:
        self.inputs: dict[str, float] = {}
        super().__init__(program, spec_path, truth_path, RegisterSource(self.inputs))
        self.clients: set[Client] = set()
        self.input_owner: dict[str, Client] = {}
        self.next_recipe_id = 1

    # --- connections --------------------------------------------------------------------------

    async def serve_client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        if self.refusing:  # a cut: the cable is out
            writer.transport.abort()
            return
        client = Client(writer, str(writer.get_extra_info("peername")))
        self.clients.add(client)
        log.info("client %s connected", client.peer)
        try:
            while True:
                header = await reader.readexactly(rtde.HEADER.size)
                length, message_type = rtde.decode_header(header)
                payload = await reader.readexactly(length)
                if self.stalled:
                    continue  # a frozen controller reads nothing into meaning and answers nothing
                self._answer(client, message_type, payload)
                await writer.drain()
        except (asyncio.IncompleteReadError, ConnectionError):
            pass
        except RobotMessageInvalid as exc:
            log.warning("client %s broke the protocol, closing: %s", client.peer, exc)
        except Exception:  # a fault of the simulator itself: said, never silent
            log.exception("client %s: the simulated controller failed", client.peer)
            raise
        finally:
            self._forget(client)
            writer.close()
            log.info("client %s disconnected", client.peer)

    def drop_all(self) -> None:
        for client in list(self.clients):
            client.writer.transport.abort()
            self._forget(client)

    def freeze(self) -> None:
        for c in self.clients:
            if c.sender is not None:
                c.sender.cancel()
                c.sender = None

    def resume(self) -> None:
        for c in self.clients:
            if c.started and c.outputs is not None and c.sender is None:
                c.sender = asyncio.get_running_loop().create_task(self._send_outputs(c))

    def outputs(self) -> dict[str, object]:
        p = self.program
        safety = SAFETY_NORMAL if p.safety == "NORMAL" else SAFETY_PROTECTIVE_STOP
        pose = tuple(float(v) for v in T_to_ur_pose(p.T_b_f_reported))
        values: dict[str, object] = {
            "timestamp": self.now(), "actual_TCP_pose": pose, "target_TCP_pose": pose,
            "actual_TCP_speed": (0.0,) * 6, "actual_q": (0.0,) * 6, "target_q": (0.0,) * 6,
            "robot_mode": ROBOT_MODE_RUNNING, "safety_mode": safety,
            "runtime_state": RUNTIME_PLAYING if p.program_running else RUNTIME_STOPPED,
            "robot_status_bits": 0b11, "safety_status_bits": 1 if safety == SAFETY_NORMAL else 0b101,
            "speed_scaling": 1.0, "target_speed_fraction": 1.0, "actual_digital_input_bits": 0,
            "actual_digital_output_bits": 0,
            rtde.ANSWER_ACK_SEQUENCE: p.ack_sequence, rtde.ANSWER_IN_POSITION: p.in_position,
            rtde.ANSWER_PROGRAM_STATUS: p.program_status, rtde.ANSWER_HELD_SEQUENCE: p.held_sequence,
            rtde.ANSWER_OFFSET_VALID: 1 if p.offset_valid else 0,
        }
        return values

    # --- private ------------------------------------------------------------------------------

    def _answer(self, client: Client, message_type: int, payload: bytes) -> None:
        send = client.writer.write
        if message_type == rtde.REQUEST_PROTOCOL_VERSION:
            version = rtde.decode_protocol_version(payload)
            ok = version in (1, 2)
            if ok:
                client.protocol_version = version
            send(rtde.encode_message(message_type, rtde.encode_accepted(ok)))
        elif message_type == rtde.GET_URCONTROL_VERSION:
            send(rtde.encode_message(message_type, rtde.encode_controller_version(*CONTROLLER_VERSION)))
        elif message_type == rtde.CONTROL_PACKAGE_SETUP_OUTPUTS:
            send(rtde.encode_message(message_type, self._setup_outputs(client, payload)))
        elif message_type == rtde.CONTROL_PACKAGE_SETUP_INPUTS:
            send(rtde.encode_message(message_type, self._setup_inputs(client, payload)))
        elif message_type == rtde.CONTROL_PACKAGE_START:
            ok = client.outputs is not None or bool(client.inputs)
            client.started = ok
            if ok and client.outputs is not None and client.sender is None:
                client.sender = asyncio.get_running_loop().create_task(self._send_outputs(client))
            send(rtde.encode_message(message_type, rtde.encode_accepted(ok)))
        elif message_type == rtde.CONTROL_PACKAGE_PAUSE:
            client.started = False
            if client.sender is not None:
                client.sender.cancel()
                client.sender = None
            send(rtde.encode_message(message_type, rtde.encode_accepted(True)))
        elif message_type == rtde.DATA_PACKAGE:
            self._receive_inputs(client, payload)
        else:
            send(rtde.encode_message(rtde.TEXT_MESSAGE, rtde.encode_text_message(
                f"message type {message_type} not accepted from a client", level=1)))

    def _setup_outputs(self, client: Client, payload: bytes) -> bytes:
        frequency, names = rtde.decode_setup_outputs(payload)
        types = [OUTPUT_TYPES.get(n, rtde.NOT_FOUND) for n in names]
        if rtde.NOT_FOUND in types or not 0 < frequency <= MAX_FREQUENCY_HZ or client.started:
            return rtde.encode_recipe(0, types)
        client.outputs = Recipe(self._new_recipe_id(), names, types, frequency)
        return rtde.encode_recipe(client.outputs.recipe_id, types)

    def _setup_inputs(self, client: Client, payload: bytes) -> bytes:
        names = rtde.decode_setup_inputs(payload)
        types = []
        for n in names:
            owner = self.input_owner.get(n)
            types.append(INPUT_TYPES.get(n, rtde.NOT_FOUND) if owner in (None, client) else rtde.IN_USE)
        if rtde.NOT_FOUND in types or rtde.IN_USE in types:
            return rtde.encode_recipe(0, types)
        recipe = Recipe(self._new_recipe_id(), names, types)
        client.inputs[recipe.recipe_id] = recipe
        for n in names:
            self.input_owner[n] = client
        return rtde.encode_recipe(recipe.recipe_id, types)

    def _receive_inputs(self, client: Client, payload: bytes) -> None:
        recipe = client.inputs.get(payload[0]) if payload else None
        if recipe is None or not client.started:
            client.writer.write(rtde.encode_message(rtde.TEXT_MESSAGE, rtde.encode_text_message(
                "data package for an unknown recipe or before start: ignored", level=2)))
            return
        _, values = rtde.decode_data_package(payload, recipe.types)
        before = self.inputs.get(rtde.REQUEST_SEQUENCE)
        self.inputs.update(zip(recipe.names, values, strict=True))  # type: ignore[arg-type]
        if self.inputs.get(rtde.REQUEST_SEQUENCE) != before and self.inputs.get(rtde.REQUEST_COMMAND) == COMMAND_OFFSET:
            self.offset_arrived()
        self.step()  # the program polls its registers every cycle (2 ms at 500 Hz): it sees them now

    async def _send_outputs(self, client: Client) -> None:
        recipe = client.outputs
        assert recipe is not None
        period = 1.0 / recipe.frequency_hz
        next_time = time.monotonic()
        while client.started and not self.stalled:
            values = self.outputs()
            client.writer.write(rtde.encode_message(rtde.DATA_PACKAGE, rtde.encode_data_package(
                recipe.recipe_id, recipe.types, [values[n] for n in recipe.names])))
            next_time += period
            await asyncio.sleep(max(0.0, next_time - time.monotonic()))

    def _forget(self, client: Client) -> None:
        if client.sender is not None:
            client.sender.cancel()
        self.clients.discard(client)
        for name in [n for n, c in self.input_owner.items() if c is client]:
            del self.input_owner[name]

    def _new_recipe_id(self) -> int:
        self.next_recipe_id = self.next_recipe_id % 255 + 1
        return self.next_recipe_id


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``python -m monoguide.drivers.sim.ur_controller``."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spec", type=Path, required=True, help="robot spec (SimCell.write_robot_spec)")
    parser.add_argument("--truth", type=Path, required=True, help="where to write what the robot did")
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, default=rtde.DEFAULT_PORT)
    add_program_arguments(parser)
    part_supply.add_arguments(parser)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, stream=sys.stderr, format="sim-ur: %(message)s")
    controller = UrController(program_from_arguments(args), args.spec, args.truth)
    return asyncio.run(serve_controller(controller, controller.serve_client, args.host, args.port, args.commands))


if __name__ == "__main__":
    sys.exit(main())
