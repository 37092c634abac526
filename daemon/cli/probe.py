"""`monoguide probe camera|tracker|robot`: is the device there, who is it, does it deliver?

Connects to the device the cell config names (real or simulated, the command does not care), prints its
identity, grabs a frame (camera, optionally saved with ``--out``) or measures a point (tracker), and exits
with a clear message and a non-zero status when the device is absent or misbehaves. The robot probe prints
identity, modes and the actual flange pose; ``--goto K`` requests measuring pose K and waits until in
position, ``--write-zero`` writes a zero offset and waits for its acknowledgement. Results go to
standard output, one line each; error lines to standard error.

A new device kind is one member of :class:`Device`, one ``_probe_<kind>(cfg, options, console)`` and
its entry in :data:`PROBES`.
"""

from __future__ import annotations

import enum
import struct
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import cv2
import numpy as np
import typer
from rich.console import Console

from monoguide.daemon.assembly import build_camera, build_robot, build_tracker, camera_settings
from monoguide.daemon.cli._console import stdout_console
from monoguide.daemon.cli._policy import fail
from monoguide.daemon.config import CellConfig, load_cell_config
from monoguide.drivers.errors import ConfigError
from monoguide.drivers.robot import RobotStatus
from monoguide.solver.errors import MonoguideError
from monoguide.solver.frames import matrix_to_rotvec
from monoguide.solver.hole_edges import bit_depth_of

OUT_SUFFIXES = (".png", ".tif", ".tiff", ".pgm", ".bmp")  # lossless: the frame is kept as grabbed


class Device(enum.StrEnum):
    camera = "camera"
    tracker = "tracker"
    robot = "robot"


@dataclass(frozen=True)
class ProbeOptions:
    """The command's options that some probe uses (each probe ignores the others)."""

    out: Path | None = None
    nest: str | None = None
    state_file: Path | None = None
    goto: int | None = None  # robot: measuring pose number (S1 is 1)
    write_zero: bool = False  # robot: write a zero offset and wait for its acknowledgement


def probe(
    device: Annotated[Device, typer.Argument(help="which device to probe")],
    config: Annotated[Path, typer.Option("--config", "-c", help="cell config (TOML)")],
    out: Annotated[Path | None, typer.Option("--out", help="save the grabbed frame (PNG)")] = None,
    nest: Annotated[str | None, typer.Option("--nest", help="tracker: the SMR nest to measure")] = None,
    state_file: Annotated[
        Path | None, typer.Option("--state-file", help="sim-cell state file (simulated tracker)")
    ] = None,
    goto: Annotated[
        int | None, typer.Option("--goto", help="robot: request measuring pose K (S1 is 1), wait until in position")
    ] = None,
    write_zero: Annotated[
        bool, typer.Option("--write-zero", help="robot: write a zero offset, wait for its acknowledgement")
    ] = False,
) -> None:
    """Connect to the camera, the laser tracker or the robot, print its identity, take one frame, point or pose."""
    console = stdout_console()
    try:
        if out is not None:
            _check_out(out)
        cfg = load_cell_config(config)
        PROBES[device](cfg, ProbeOptions(out, nest, state_file, goto, write_zero), console)
    except ConfigError as exc:
        fail(exc)  # exit 2: the config's key named
    except MonoguideError as exc:
        fail(exc, f"{device.value} failed")


def _probe_camera(cfg: CellConfig, options: ProbeOptions, console: Console) -> None:
    out = options.out
    camera = build_camera(cfg)
    identity = camera.open()
    try:
        _say(console, f"camera: {identity.vendor} {identity.model}, serial {identity.serial}"
             + (f", user name {identity.user_name}" if identity.user_name else ""))
        camera.configure(camera_settings(cfg))
        frame = camera.grab(cfg.camera.grab_timeout_s)
    finally:
        camera.close()
    image = frame.image
    _say(console, f"frame {frame.frame_number}: {image.shape[1]} x {image.shape[0]} px {frame.pixel_format}, "
         f"grey min {int(image.min())} mean {float(np.mean(image)):.1f} max {int(image.max())}")
    if out is not None:
        try:
            written = cv2.imwrite(str(out), image)
        except cv2.error as exc:
            raise ConfigError(f"--out {out}: cannot write the image: {exc}") from exc
        if not written:
            raise ConfigError(f"--out {out}: cannot write the image there")
        bits = _significant_bits(frame.pixel_format)
        if out.suffix.lower() == ".png" and image.dtype == np.uint16 and bits is not None and bits < 16:
            out.write_bytes(png_with_significant_bits(out.read_bytes(), bits))
        _say(console, f"saved {out}" + (f" ({bits} significant bits, in its sBIT chunk)" if bits and bits < 16
                                        and image.dtype == np.uint16 else ""))


def _significant_bits(pixel_format: str) -> int | None:
    """Bits of a GenICam mono format (Mono12 -> 12), or None for another format."""
    try:
        return bit_depth_of(pixel_format)
    except MonoguideError:
        return None


def png_with_significant_bits(png: bytes, bits: int) -> bytes:
    """The PNG with an sBIT chunk saying that its 16-bit grey samples hold ``bits`` significant bits (a
    Mono10/Mono12 frame), so that ``monoguide detect`` scales it by 2**bits - 1 and not by 65535."""
    ihdr_end = 8 + 8 + 13 + 4  # signature, IHDR length and type, its 13 bytes, CRC
    if png[12:16] != b"IHDR" or png[25] != 0:  # colour type 0: grey (a mono frame)
        return png
    body = b"sBIT" + bytes([bits])
    chunk = struct.pack(">I", 1) + body + struct.pack(">I", zlib.crc32(body))
    return png[:ihdr_end] + chunk + png[ihdr_end:]


def _check_out(out: Path) -> None:
    """Refuse an ``--out`` that cannot be written before touching the device."""
    if out.suffix.lower() not in OUT_SUFFIXES:
        raise ConfigError(f"--out {out}: the image format is chosen by the suffix, one of {list(OUT_SUFFIXES)}")
    if not out.parent.is_dir():
        raise ConfigError(f"--out {out}: folder {out.parent} does not exist")


def _probe_tracker(cfg: CellConfig, options: ProbeOptions, console: Console) -> None:
    nest = options.nest
    tracker = build_tracker(cfg, options.state_file)
    identity = tracker.open()
    try:
        _say(console, f"tracker: {identity.vendor} {identity.model}, serial {identity.serial}, "
             f"firmware {identity.firmware}")
        m = tracker.measure_point(nest)
    finally:
        tracker.close()
    x, y, z = (float(v) for v in m.point_mm)
    _say(console, f"point{' ' + nest if nest else ''}: x {x:.4f} y {y:.4f} z {z:.4f} mm, "
         f"rms {m.rms_mm:.4f} mm, measurement {m.measurement_number}")


def _probe_robot(cfg: CellConfig, options: ProbeOptions, console: Console) -> None:
    n = len(cfg.cell_poses)
    if options.goto is not None and not 1 <= options.goto <= n:
        raise ConfigError(f"--goto {options.goto}: the cell has measuring poses 1..{n} "
                          f"({', '.join(p.name for p in cfg.cell_poses)})")
    robot = build_robot(cfg, options.state_file)
    identity = robot.open()
    try:
        _say(console, f"robot: {identity.vendor} {identity.model}, software {identity.software}, at "
             f"{identity.address}")
        _say_robot_status(console, robot.status(), cfg)
        if options.goto is not None:
            i = options.goto - 1
            status = robot.move_to_measuring_pose(i)
            _say(console, f"in position at {cfg.cell_poses[i].name} (request {status.ack_sequence})")
            _say_robot_status(console, status, cfg)
        if options.write_zero:
            sequence = robot.write_base_offset(np.eye(4))
            _say(console, f"zero offset written, acknowledged as request {sequence}")
    finally:
        robot.close()


def _say_robot_status(console: Console, status: RobotStatus, cfg: CellConfig) -> None:
    at = cfg.cell_poses[status.in_position - 1].name if 1 <= status.in_position <= len(cfg.cell_poses) \
        else "no measuring pose"
    _say(console, f"mode {status.mode}, safety {status.safety}, program "
         f"{'running' if status.program_running else 'NOT running'}, {'ready' if status.ready else 'NOT READY'}, "
         f"at {at}")
    x, y, z = (float(v) for v in status.T_b_f[:3, 3])
    rx, ry, rz = (float(v) for v in np.degrees(matrix_to_rotvec(status.T_b_f[:3, :3])))
    _say(console, f"flange T_b_f: x {x:.3f} y {y:.3f} z {z:.3f} mm, rotation vector {rx:.4f} {ry:.4f} {rz:.4f} deg")


def _say(console: Console, line: str) -> None:
    """One result line, printed as is (device names and paths may hold ``[...]`` that is not markup)."""
    console.print(line, markup=False)


PROBES: dict[Device, Callable[[CellConfig, ProbeOptions, Console], None]] = {
    Device.camera: _probe_camera,
    Device.tracker: _probe_tracker,
    Device.robot: _probe_robot,
}
