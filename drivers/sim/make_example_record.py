"""Write ``examples/example-record.json``, a synthetic measurement record of the simulated cell.

``python -m monoguide.drivers.sim.make_example_record examples/example-record.json`` (stdout without an
argument; ``--config PATH`` for another cell file than ``config/sim-cell.toml``).

The record is the cell of the config file: its camera, featured points, measuring poses and reference
part pose, expressed in SF1 (the first measuring pose), and ``T_b_s1 = inv(T_cf_b) @ T_cf_s1``. The part
lies off the reference by a seeded deviation (:data:`SEED`: each rotation-vector component uniform in
+-:data:`DEVIATION_DEG` about the holes' centroid, each shift component in +-:data:`DEVIATION_MM`); its
pixels are the exact projections of that part plus Gaussian noise of :data:`SIGMA_PX`. Matrices are
printed to 6 decimals and the cell is projected as the reader reads them back (rounded, then
orthonormalised), so that the printed record is self-consistent; pixels to 3 decimals. ``truth`` holds
the true part pose and the true base offset. Edit this generator, not the example.
"""

from __future__ import annotations

import argparse
import json
import sys
import tomllib
from pathlib import Path
from typing import Any

import numpy as np

from monoguide.solver import frames
from monoguide.solver.camera import CameraModel
from monoguide.solver.errors import MonoguideError
from monoguide.solver.synthetic import SyntheticCell, calibrated_cell, deviated_part, measurement_record

SEED = 20261123
DEVIATION_DEG, DEVIATION_MM = 2.0, 30.0
SIGMA_PX = 0.1
RECORD_ID = "example-1"
ENVELOPE = {"mm": 50.0, "deg": 5.0}  # the line's envelope (the spec's default, written out)
MATRIX_DECIMALS, POINT_DECIMALS, PIXEL_DECIMALS = 6, 3, 3
DEFAULT_CONFIG = Path("config/sim-cell.toml")
KEY_ORDER = (
    "format", "id", "camera", "points_w", "views", "T_s1_w0", "observations", "sigma_px", "T_b_s1",
    "grasp_point_w", "envelope", "truth",
)


def example_record(config: dict[str, Any]) -> dict[str, Any]:
    """The example record (a JSON-ready dict, keys in the spec's order) of a parsed cell config (its first part
    type, job 1, in a cell of ``[[parts]]``)."""
    config = _first_part_type(config)
    camera = CameraModel.from_dict(_key(config, "camera", "intrinsics"))
    points_w = np.round(np.array(_key(config, "part", "points_w"), dtype=float), POINT_DECIMALS)
    poses = _key(config, "measuring_poses")
    T_cf_si = [np.array(_key(pose, "T_cf_si"), dtype=float) for pose in poses]
    T_cf_w0 = np.array(_key(config, "reference", "T_cf_w0"), dtype=float)
    T_cf_b = np.array(_key(config, "reference", "T_cf_b"), dtype=float)
    cell = _as_printed(calibrated_cell(camera, points_w, T_cf_w0, T_cf_si, [_key(p, "points") for p in poses]))
    T_b_s1 = _printed(frames.invert(T_cf_b) @ T_cf_si[0], "T_b_s1")
    rng = np.random.default_rng(SEED)
    T_true = _printed(deviated_part(cell, rng, DEVIATION_DEG, DEVIATION_MM), "truth.T_s1_w")
    pixels = cell.project(T_true) + rng.normal(0.0, SIGMA_PX, (len(cell.observed), 2))
    record = measurement_record(cell, np.round(pixels, PIXEL_DECIMALS), SIGMA_PX, RECORD_ID, T_b_s1, T_true)
    record["grasp_point_w"] = points_w.mean(axis=0).round(POINT_DECIMALS).tolist()
    record["envelope"] = dict(ENVELOPE)
    return {key: _rounded(record[key]) for key in KEY_ORDER}


def example_record_json(config_path: Path) -> str:
    """The text of the example for the cell config at ``config_path``: one matrix row, one point, one
    pixel per line."""
    with open(config_path, "rb") as f:
        config = tomllib.load(f)
    return _dumps(example_record(config)) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m monoguide.drivers.sim.make_example_record",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("out", nargs="?", type=Path, help="where to write the record (stdout without it)")
    parser.add_argument("--config", type=Path, default=DEFAULT_CONFIG, help=f"the cell (default {DEFAULT_CONFIG})")
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    try:
        text = example_record_json(args.config)
    except (OSError, ValueError, MonoguideError) as error:  # a TOMLDecodeError is a ValueError
        sys.stderr.write(f"{args.config}: {error}\n")
        return 1
    if args.out is None:
        sys.stdout.write(text)
    else:
        args.out.write_text(text)
    return 0


# --- private -----------------------------------------------------------------------------------


class _MissingConfigKey(ValueError):
    """The cell config lacks a key the example needs."""


def _first_part_type(config: dict[str, Any]) -> dict[str, Any]:
    """A cell of ``[[parts]]`` as the single-part form of its first part: ``[part]``, ``[reference] T_cf_w0`` and
    its poses with ``points`` (indices of its holes); a single-part config as it is."""
    if "parts" not in config:
        return config
    part = _key(config, "parts")[0]
    names = list(part.get("point_names") or [f"P{i + 1}" for i in range(len(_key(part, "points_w")))])
    views = _key(part, "measuring_poses")
    poses = [dict(pose, points=[names.index(h) for h in views[pose["name"]]])
             for pose in _key(config, "measuring_poses") if pose.get("name") in views]
    reference = dict(config.get("reference", {}), T_cf_w0=_key(part, "T_cf_w0"))
    return {**config, "part": part, "reference": reference, "measuring_poses": poses}


def _key(table: dict[str, Any], *path: str) -> Any:
    value = table
    for depth, key in enumerate(path):
        if not isinstance(value, dict) or key not in value:
            raise _MissingConfigKey(f"missing key {'.'.join(path[: depth + 1])!r}")
        value = value[key]
    return value


def _printed(T: np.ndarray, name: str) -> np.ndarray:
    """``T`` as the reader reads it back from its printed digits: rounded, then orthonormalised."""
    return frames.rigid_transform(np.round(T, MATRIX_DECIMALS), name)


def _as_printed(cell: SyntheticCell) -> SyntheticCell:
    T_s1_si = np.stack([_printed(T, f"views[{i}].T_s1_si") for i, T in enumerate(cell.T_s1_si)])
    return SyntheticCell(cell.camera, cell.points_w, T_s1_si, _printed(cell.T_s1_w0, "T_s1_w0"), cell.observed)


def _rounded(value: Any) -> Any:
    """Floats to :data:`MATRIX_DECIMALS` (pixels and points are rounded before), without negative zeros."""
    if isinstance(value, dict):
        return {k: _rounded(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_rounded(v) for v in value]
    if isinstance(value, float):
        return round(value, MATRIX_DECIMALS) + 0.0
    return value


def _dumps(value: Any, indent: int = 0) -> str:
    """JSON with objects and lists of lists spread over lines (one space per level), lists of numbers
    on one line."""
    pad, inner = " " * indent, " " * (indent + 1)
    if isinstance(value, dict) and value:
        items = [f"{inner}{json.dumps(k)}: {_dumps(v, indent + 1)}" for k, v in value.items()]
        return "{\n" + ",\n".join(items) + "\n" + pad + "}"
    if isinstance(value, list) and any(isinstance(v, dict | list) for v in value):
        return "[\n" + ",\n".join(inner + _dumps(v, indent + 1) for v in value) + "\n" + pad + "]"
    if isinstance(value, list):
        return "[" + ", ".join(json.dumps(v) for v in value) + "]"
    return json.dumps(value)


if __name__ == "__main__":
    sys.exit(main())
