"""`monoguide probe camera|tracker`: is the device there, who is it, does it deliver?

Connects to the device the cell config names (real or simulated, the command does not care), prints its
identity, grabs a frame (camera, optionally saved with ``--out``) or measures a point (tracker), and exits
with a clear message and a non-zero status when the device is absent or misbehaves.
"""

from __future__ import annotations

import enum
from pathlib import Path
from typing import Annotated

import cv2
import numpy as np
import typer
from rich.console import Console
from rich.markup import escape

from monoguide.daemon.assembly import build_camera, build_tracker, camera_settings
from monoguide.daemon.config import CellConfig, load_cell_config
from monoguide.drivers.errors import ConfigError
from monoguide.solver.errors import MonoguideError

EXIT_DEVICE = 1
EXIT_CONFIG = 2
OUT_SUFFIXES = (".png", ".tif", ".tiff", ".pgm", ".bmp")  # lossless: the frame is kept as grabbed


class Device(enum.StrEnum):
    camera = "camera"
    tracker = "tracker"


def probe(
    device: Annotated[Device, typer.Argument(help="which device to probe")],
    config: Annotated[Path, typer.Option("--config", "-c", help="cell config (TOML)")],
    out: Annotated[Path | None, typer.Option("--out", help="save the grabbed frame (PNG)")] = None,
    nest: Annotated[str | None, typer.Option("--nest", help="tracker: the SMR nest to measure")] = None,
    state_file: Annotated[
        Path | None, typer.Option("--state-file", help="sim-cell state file (simulated tracker)")
    ] = None,
) -> None:
    """Connect to the camera or the laser tracker, print its identity, take one frame or point."""
    # markup=False: messages quote config sections ("[camera].region") that rich would take for tags;
    # soft_wrap: one line per result, whatever the terminal width, so scripts can read it
    console = Console(highlight=False, markup=False, soft_wrap=True)
    errors = Console(stderr=True, highlight=False, soft_wrap=True)
    try:
        if out is not None:
            _check_out(out)
        cfg = load_cell_config(config)
        if device is Device.camera:
            _probe_camera(cfg, out, console)
        else:
            _probe_tracker(cfg, nest, state_file, console)
    except ConfigError as exc:
        errors.print(f"[red]config error {exc.code}[/red] (PLC {exc.plc_code}): {escape(exc.message)}")
        raise typer.Exit(EXIT_CONFIG) from exc
    except MonoguideError as exc:
        errors.print(f"[red]{device.value} failed: {exc.code}[/red] (PLC {exc.plc_code}): {escape(exc.message)}")
        raise typer.Exit(EXIT_DEVICE) from exc


def _probe_camera(cfg: CellConfig, out: Path | None, console: Console) -> None:
    camera = build_camera(cfg)
    identity = camera.open()
    try:
        console.print(f"camera: {identity.vendor} {identity.model}, serial {identity.serial}"
                      + (f", user name {identity.user_name}" if identity.user_name else ""))
        camera.configure(camera_settings(cfg))
        frame = camera.grab(cfg.camera.grab_timeout_s)
    finally:
        camera.close()
    image = frame.image
    console.print(f"frame {frame.frame_number}: {image.shape[1]} x {image.shape[0]} px {frame.pixel_format}, "
                  f"grey min {int(image.min())} mean {float(np.mean(image)):.1f} max {int(image.max())}")
    if out is not None:
        try:
            written = cv2.imwrite(str(out), image)
        except cv2.error as exc:
            raise ConfigError(f"--out {out}: cannot write the image: {exc}") from exc
        if not written:
            raise ConfigError(f"--out {out}: cannot write the image there")
        console.print(f"saved {out}")


def _check_out(out: Path) -> None:
    """Refuse an ``--out`` that cannot be written before touching the device."""
    if out.suffix.lower() not in OUT_SUFFIXES:
        raise ConfigError(f"--out {out}: the image format is chosen by the suffix, one of {list(OUT_SUFFIXES)}")
    if not out.parent.is_dir():
        raise ConfigError(f"--out {out}: folder {out.parent} does not exist")


def _probe_tracker(cfg: CellConfig, nest: str | None, state_file: Path | None, console: Console) -> None:
    tracker = build_tracker(cfg, state_file)
    identity = tracker.open()
    try:
        console.print(f"tracker: {identity.vendor} {identity.model}, serial {identity.serial}, "
                      f"firmware {identity.firmware}")
        m = tracker.measure_point(nest)
    finally:
        tracker.close()
    x, y, z = (float(v) for v in m.point_mm)
    console.print(f"point{' ' + nest if nest else ''}: x {x:.4f} y {y:.4f} z {z:.4f} mm, "
                  f"rms {m.rms_mm:.4f} mm, measurement {m.measurement_number}")
