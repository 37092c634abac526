"""Write the calibration of a cell whose camera has since been bumped on its bracket, for ``monoguide simulate
--calibration`` (issue 20, "Why"): the cell config with ``[camera] T_f_c`` and every ``[[measuring_poses]] T_cf_si``
right-multiplied by the inverse of the bump ``B`` (``deg`` about and ``mm`` along the camera's own ``axis``,
drivers/sim/calibration_faults.py ``bump_motion``), everything else as it was. The taught flange poses that
follow from it (``T_cf_b⁻¹ · T_cf_si · T_f_c⁻¹``) are unchanged; the simulated cell keeps the truth, so the camera
truly stands at the calibrated pose right-multiplied by ``B`` — the same as sim-cell's ``camera bump DEG MM AXIS``.

    .venv/bin/python benchmarks/make_bumped_calibration.py --deg 0.1 --axis x --mm 0 --out BUMPED.toml
    .venv/bin/monoguide simulate --calibration BUMPED.toml --cycles 8 --seed 5

The file is edited in place with tomlkit (comments and layout kept; matrices written as the calibration wizard
writes them, drivers/toml_format.py).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import tomlkit

from monoguide.drivers.sim.calibration_faults import bump_motion
from monoguide.drivers.toml_format import matrix, opening_comment
from monoguide.solver.calibration_faults import AXES
from monoguide.solver.frames import compose, invert

SIM_CELL = Path(__file__).parents[1] / "config" / "sim-cell.toml"


def bumped_calibration(text: str, deg: float, mm: float, axis: str = "x") -> str:
    """``text`` (a cell config) with ``[camera] T_f_c`` and every ``[[measuring_poses]] T_cf_si`` right-multiplied
    by the inverse of the bump; a :class:`ValueError` naming a missing table or key."""
    doc = tomlkit.parse(text)
    inverse = invert(bump_motion(deg, mm, axis))
    camera = doc.get("camera")
    if camera is None or "T_f_c" not in camera:
        raise ValueError("no [camera] T_f_c to bump")
    poses = doc.get("measuring_poses") or []
    if not poses or any("T_cf_si" not in pose for pose in poses):
        raise ValueError("every [[measuring_poses]] needs a T_cf_si to bump")
    for table in (camera, *poses):
        key = "T_f_c" if table is camera else "T_cf_si"
        value = compose(np.asarray(table[key].unwrap(), dtype=float), inverse)
        table[key] = matrix(value.tolist(), comment=opening_comment(table[key]))
    return tomlkit.dumps(doc)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--deg", type=float, default=0.0, help="rotation about the camera's axis, deg")
    parser.add_argument("--mm", type=float, default=0.0, help="translation along the camera's axis, mm")
    parser.add_argument("--axis", choices=AXES, default="x", help="the camera's own axis (default x)")
    parser.add_argument("--config", type=Path, default=SIM_CELL, help="the cell config (default config/sim-cell.toml)")
    parser.add_argument("--out", type=Path, required=True, help="the bumped calibration file to write")
    args = parser.parse_args()
    try:
        out = bumped_calibration(args.config.read_text(), args.deg, args.mm, args.axis)
    except (OSError, ValueError) as exc:
        sys.exit(f"{args.config}: {exc}")
    args.out.write_text(out)
    print(f"{args.out}: {args.config} with [camera] T_f_c and every T_cf_si right-multiplied by the inverse of a "
          f"bump of {args.deg:g} deg about and {args.mm:g} mm along the camera's {args.axis} axis")


if __name__ == "__main__":
    main()
