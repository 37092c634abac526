"""``monoguide detect``: images in, sub-pixel hole centres out (docs/detect.md)."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated, Any

import cv2
import typer
from rich.console import Console
from rich.table import Table

from monoguide.solver.errors import (
    BadImage,
    HoleCutByBorder,
    HoleNotFound,
    ImageSaturated,
    LowContrast,
    MonoguideError,
)
from monoguide.solver.holes import DEFAULT_RADIUS_TOL, HoleScan, scan_holes

# When no hole was found, the refused blob that explains it best: the most specific reason first.
_REASON_PRIORITY = (ImageSaturated, HoleCutByBorder, LowContrast, HoleNotFound)


def detect(
    images: Annotated[list[str], typer.Argument(help="Image files: PNG, TIFF, BMP...; grey or colour, 8 or 16 bit.")],
    json_output: Annotated[bool, typer.Option("--json", help="One JSON object per image per line.")] = False,
    roi: Annotated[str | None, typer.Option("--roi", help="Search only here: X,Y,W,H in pixels.")] = None,
    radius_px: Annotated[
        float | None, typer.Option("--radius-px", help="Only holes of this radius (+-25 %), pixels.")
    ] = None,
) -> None:
    """Find the holes in each image and print their sub-pixel centres, most plausible first.

    Pixel coordinates are raw image coordinates (x right, y down, pixel centres at integers); axes are
    the ellipse's semi-axes. With --radius-px only holes within 25 % of that radius are listed. The
    exit status is 1 when any image failed.
    """
    roi_box = _parse_roi(roi)
    if radius_px is not None and not radius_px > 0:
        raise typer.BadParameter(f"must be positive, got {radius_px}", param_hint="--radius-px")
    results = [_detect_one(path, roi_box, radius_px) for path in images]
    if json_output:
        for result in results:
            sys.stdout.write(json.dumps(result) + "\n")
    else:
        _print_table(results)
    if any(result["status"] != "ok" for result in results):
        raise typer.Exit(1)


def _detect_one(path: str, roi: tuple[int, int, int, int] | None, radius_px: float | None) -> dict[str, Any]:
    """The JSON result of one image: status, holes (most plausible first), error."""
    try:
        image = _read_image(path)
        scan = scan_holes(image, roi=roi, expected_radius_px=radius_px)
        holes = [h for h in scan.holes if radius_px is None or abs(h.mean_radius / radius_px - 1) <= DEFAULT_RADIUS_TOL]
        if not holes:
            raise _why_nothing(scan, roi, radius_px)
    except MonoguideError as error:
        return {"image": path, "status": "error", "holes": [], "error": error.as_dict()}
    except ValueError as error:  # a ROI outside the image
        return {"image": path, "status": "error", "holes": [],
                "error": {"code": BadImage.code, "message": str(error)}}
    return {"image": path, "status": "ok", "holes": [hole.as_dict() for hole in holes], "error": None}


def _read_image(path: str) -> Any:
    if not Path(path).is_file():
        raise BadImage(f"{path}: no such file")
    image = cv2.imread(path, cv2.IMREAD_UNCHANGED)
    if image is None:
        raise BadImage(f"{path}: not an image OpenCV can read")
    return image


def _why_nothing(scan: HoleScan, roi: tuple[int, int, int, int] | None, radius_px: float | None) -> MonoguideError:
    where = "the image" if roi is None else f"roi {','.join(str(v) for v in roi)}"
    if scan.holes and radius_px is not None:
        seen = ", ".join(f"r={h.mean_radius:.1f}" for h in scan.holes[:5])
        return HoleNotFound(f"{where}: no hole of radius {radius_px:.1f} px +-25 %; seen {seen}")
    if scan.saturated_fraction > 0.5:
        return ImageSaturated(f"{where}: {100 * scan.saturated_fraction:.0f} % of the pixels are saturated")
    for kind in _REASON_PRIORITY:
        for blob in scan.refused:
            if isinstance(blob.error, kind):
                return blob.error
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
    return x, y, w, h


def _print_table(results: list[dict[str, Any]]) -> None:
    console = Console()
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
    console.print(table)
    for result in results:
        if result["status"] != "ok":
            console.print(f"[red]{result['error']['code']}[/red] {result['error']['message']}", soft_wrap=True)
