"""``monoguide detect``: images in, sub-pixel hole centres out (docs/detect.md)."""

from __future__ import annotations

import json
import math
import struct
import sys
from pathlib import Path
from typing import Annotated, Any

import cv2
import numpy as np
import typer
from rich.table import Table

from monoguide.daemon.cli._console import say, stderr_console, stdout_console
from monoguide.solver.errors import (
    BadImage,
    HoleCutByBorder,
    HoleNotFound,
    ImageSaturated,
    LowContrast,
    MonoguideError,
)
from monoguide.solver.holes import DEFAULT_MIN_RADIUS_PX, DEFAULT_RADIUS_TOL, HoleScan, scan_holes

# When no hole was found, the refused blob that explains it best: the most specific reason first.
_REASON_PRIORITY = (ImageSaturated, HoleCutByBorder, LowContrast, HoleNotFound)
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def detect(
    images: Annotated[list[str], typer.Argument(help="Image files: PNG, TIFF, BMP...; grey or colour, 8 or 16 bit.")],
    json_output: Annotated[bool, typer.Option("--json", help="One JSON object per image per line.")] = False,
    roi: Annotated[
        str | None, typer.Option("--roi", help="Only holes whose centre lies here: X,Y,W,H in pixels.")
    ] = None,
    radius_px: Annotated[
        float | None, typer.Option("--radius-px", help="Only holes of this radius (+-25 %), pixels.")
    ] = None,
    bit_depth: Annotated[
        int | None,
        typer.Option("--bit-depth", min=8, max=16,
                     help="Significant bits of 16-bit images (Mono10 -> 10, Mono12 -> 12). Default: the PNG's "
                          "sBIT chunk, else 16."),
    ] = None,
) -> None:
    """Find the holes in each image and print their sub-pixel centres, most plausible first.

    Pixel coordinates are raw image coordinates (x right, y down, pixel centres at integers); axes are
    the ellipse's semi-axes. With --radius-px only holes within 25 % of that radius are listed. The
    exit status is 1 when any image failed, 2 for a bad option.
    """
    roi_box = _parse_roi(roi)
    if radius_px is not None and not (math.isfinite(radius_px) and radius_px > 0):
        raise typer.BadParameter(f"must be a positive number of pixels, got {radius_px}", param_hint="--radius-px")
    results = [_detect_one(path, roi_box, radius_px, bit_depth) for path in images]
    if json_output:
        for result in results:
            sys.stdout.write(json.dumps(result) + "\n")
    else:
        _print_table(results)
    if any(result["status"] != "ok" for result in results):
        raise typer.Exit(1)


def _detect_one(
    path: str, roi: tuple[int, int, int, int] | None, radius_px: float | None, bit_depth: int | None = None
) -> dict[str, Any]:
    """The JSON result of one image: status, holes (most plausible first), error."""
    image = None
    try:
        image = _read_image(path)
        depth = bit_depth if bit_depth is not None or image.dtype != np.uint16 else _png_significant_bits(path)
        scan = scan_holes(image, roi=roi, expected_radius_px=radius_px, bit_depth=depth)
        holes = [h for h in scan.holes if radius_px is None or abs(h.mean_radius / radius_px - 1) <= DEFAULT_RADIUS_TOL]
        if not holes:
            raise _why_nothing(scan, roi, radius_px)
    except MonoguideError as error:
        message = error.message + _bit_depth_hint(image, bit_depth, error)
        return {"image": path, "status": "error", "holes": [], "error": {"code": error.code, "message": message}}
    except ValueError as error:  # a ROI outside the image
        return {"image": path, "status": "error", "holes": [],
                "error": {"code": BadImage.code, "message": f"{path}: {error}"}}
    return {"image": path, "status": "ok", "holes": [hole.as_dict() for hole in holes], "error": None}


def _read_image(path: str) -> Any:
    if not Path(path).is_file():
        raise BadImage(f"{path}: no such file")
    image = cv2.imread(path, cv2.IMREAD_UNCHANGED)
    if image is None:
        raise BadImage(f"{path}: not an image OpenCV can read")
    return image


def _png_significant_bits(path: str) -> int | None:
    """The significant bits of a 16-bit PNG's grey (or colour) samples from its sBIT chunk, or None."""
    with open(path, "rb") as file:
        if file.read(8) != _PNG_SIGNATURE:
            return None
        while True:
            header = file.read(8)
            if len(header) < 8:
                return None
            length, kind = struct.unpack(">I4s", header)
            if kind == b"sBIT":
                bits = max(file.read(min(length, 4)) or b"\x00")
                return bits if 8 <= bits <= 16 else None
            if kind in (b"IDAT", b"IEND"):  # sBIT must come before the image data
                return None
            file.seek(length + 4, 1)


def _bit_depth_hint(image: Any, bit_depth: int | None, error: MonoguideError) -> str:
    """A hint when a 16-bit image read at full 16-bit scale looks like 10/12/14-bit data."""
    if bit_depth is not None or not isinstance(image, np.ndarray) or image.dtype != np.uint16:
        return ""
    if not isinstance(error, LowContrast | HoleNotFound):
        return ""
    top = int(image.max())
    for bits in (10, 12, 14):
        if top < 2**bits:
            return f" (the 16-bit image's largest value is {top}: {bits}-bit data? give --bit-depth {bits})"
    return ""


def _why_nothing(scan: HoleScan, roi: tuple[int, int, int, int] | None, radius_px: float | None) -> MonoguideError:
    where = "the image" if roi is None else f"roi {','.join(str(v) for v in roi)}"
    seen = [*scan.holes, *scan.wrong_size]
    if seen:
        listed = ", ".join(f"r={h.mean_radius:.1f}" for h in seen[:5])
        size = f"{radius_px:.1f} px +-25 %" if radius_px is not None else "a plausible size"
        return HoleNotFound(f"{where}: no hole of radius {size}; seen {listed}")
    if scan.saturated_fraction > 0.5:
        return ImageSaturated(f"{where}: {100 * scan.saturated_fraction:.0f} % of the pixels are saturated")
    # only blobs of a hole's size explain the failure: specks of noise cut by the border do not
    r_min = 0.6 * radius_px if radius_px is not None else DEFAULT_MIN_RADIUS_PX
    sized = [blob for blob in scan.refused if blob.radius_px >= 0.7 * r_min]
    for kind in _REASON_PRIORITY[:-1]:
        for blob in sized:
            if isinstance(blob.error, kind):
                return blob.error
    if sized:
        return HoleNotFound(f"{where}: none of {len(sized)} dark blobs is a hole; the first: {sized[0].error.message}")
    return HoleNotFound(f"{where}: nothing dark of a hole's size")


def _parse_roi(text: str | None) -> tuple[int, int, int, int] | None:
    if text is None:
        return None
    try:
        x, y, w, h = (int(part) for part in text.split(","))
    except ValueError as exc:
        raise typer.BadParameter(f"expected X,Y,W,H (four integers), got {text!r}", param_hint="--roi") from exc
    if w <= 0 or h <= 0:
        raise typer.BadParameter(f"width and height must be positive, got {text!r}", param_hint="--roi")
    if x < 0 or y < 0:
        raise typer.BadParameter(f"X and Y must not be negative, got {text!r}", param_hint="--roi")
    return x, y, w, h


def _print_table(results: list[dict[str, Any]]) -> None:
    table = Table(title="monoguide detect")
    table.add_column("image", overflow="fold")
    table.add_column("status")
    for column in ("#", "u px", "v px", "a px", "b px", "angle °", "score"):
        table.add_column(column, justify="right", no_wrap=True)
    for result in results:
        if result["status"] != "ok":
            table.add_row(result["image"], f"[red]{result['error']['code']}[/red]", end_section=True)
            continue
        for i, hole in enumerate(result["holes"]):
            table.add_row(result["image"] if i == 0 else "", "ok" if i == 0 else "", str(i + 1),
                          f"{hole['center'][0]:.3f}", f"{hole['center'][1]:.3f}", f"{hole['axes'][0]:.2f}",
                          f"{hole['axes'][1]:.2f}", f"{hole['angle_deg']:.1f}", f"{hole['score']:.2f}",
                          end_section=i == len(result["holes"]) - 1)
    stdout_console().print(table)
    errors = stderr_console()
    for result in results:
        if result["status"] != "ok":
            message = result["error"]["message"]
            if not message.startswith(result["image"]):
                message = f"{result['image']}: {message}"
            say(errors, f"{result['error']['code']} {message}")
