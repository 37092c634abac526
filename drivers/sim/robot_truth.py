"""The simulated robot's files: the spec it reads (what it knows of the cell) and the truth file it writes (what it
did and holds), and the scores both give: the grasp error of an offset, its size at the grasp point.

The spec is written by :meth:`~monoguide.drivers.sim.cell.SimCell.write_robot_spec` (re-read when it changes: a new
part); the truth file by the controller's program (:mod:`monoguide.drivers.sim.robot_motion`), read by tests, the
simulated camera (:func:`follow_truth`) and the simulated tracker (the flange SMR).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from monoguide.drivers.atomic_file import write_atomic
from monoguide.drivers.sim.cell import ROBOT_SPEC_FORMAT, SimCell
from monoguide.solver.frames import compose, invert, matrix_to_rotvec, pose_difference

TRUTH_FORMAT = "monoguide.sim-robot-truth/1"


@dataclass(frozen=True)
class RobotSpec:
    """What the simulated robot knows of the cell (all in its base frame, mm)."""

    part: int
    seed: int
    repeatability_mm: float
    repeatability_deg: float
    T_b_f_taught: tuple[np.ndarray, ...]
    T_b_w0: np.ndarray
    T_b_w: np.ndarray
    T_b_g0: np.ndarray
    T_b_f_calibration: tuple[np.ndarray, ...] = ()  # base-calibration poses 1..N: wire pose numbers 101..100+N
    reported_fraction: float = 1.0  # share of each stop's deviation the controller's reported pose sees


def offset_size(D_b: np.ndarray, T_b_g0: np.ndarray) -> tuple[float, float]:
    """How far ``D_b`` moves the taught grasp point (mm) and how far it turns (deg): the programs' own limits."""
    moved = compose(D_b, T_b_g0)
    return float(np.linalg.norm(moved[:3, 3] - T_b_g0[:3, 3])), float(np.degrees(np.linalg.norm(
        matrix_to_rotvec(np.asarray(D_b, dtype=float)[:3, :3]))))


def grasp_error(D_b: np.ndarray, T_b_g0: np.ndarray, T_b_w: np.ndarray, T_b_w0: np.ndarray) -> tuple[float, float]:
    """The grasp pose offset ``D_b`` makes of the taught one, ``D_b · T_b_g0`` (what ``pose_trans`` does),
    against the ideal one ``T_b_w · T_b_w0⁻¹ · T_b_g0``: (distance mm at the TCP, angle deg)."""
    angle_deg, distance_mm = pose_difference(compose(D_b, T_b_g0), compose(T_b_w, invert(T_b_w0), T_b_g0))
    return distance_mm, angle_deg


def load_robot_spec(path: Path) -> RobotSpec:
    data = json.loads(Path(path).read_text())
    if data.get("format") != ROBOT_SPEC_FORMAT:
        raise ValueError(f"{path}: format must be {ROBOT_SPEC_FORMAT!r}, got {data.get('format')!r}")
    m = {k: np.asarray(data[k], dtype=float) for k in ("T_b_w0", "T_b_w", "T_b_g0")}
    return RobotSpec(int(data["part"]), int(data["seed"]), float(data["repeatability_mm"]),
                     float(data["repeatability_deg"]),
                     tuple(np.asarray(T, dtype=float) for T in data["T_b_f_taught"]), **m,
                     T_b_f_calibration=tuple(np.asarray(T, dtype=float) for T in data.get("T_b_f_calibration", ())),
                     reported_fraction=float(data.get("reported_repeatability_fraction", 1.0)))


def write_truth(path: Path, truth: dict[str, object]) -> None:
    write_atomic(path, json.dumps(truth))


def read_truth(path: Path) -> dict[str, object]:
    """The truth file of a simulated controller (what it did); matrices as nested lists."""
    data = json.loads(Path(path).read_text())
    if data.get("format") != TRUTH_FORMAT:
        raise ValueError(f"{path}: format must be {TRUTH_FORMAT!r}, got {data.get('format')!r}")
    return data


def follow_truth(cell: SimCell, path: Path) -> int:
    """Let an in-process :class:`SimCell` (the simulated camera's) stand where the simulated controller's robot
    stands: every stop it made, then its current measuring pose; and hold the part the controller's part
    supply presents (``T_cf_w``), when it has one and no operator has put a part of their own in the cell's scene
    (the calibration wizard's). Returns that pose number (0: moving)."""
    truth = read_truth(path)
    if truth.get("T_cf_w") is not None and (cell.scene is None or cell.scene.part is None):
        if truth.get("part_type") is not None and cell.spec.part_types:
            cell.set_part_type(int(truth["part_type"]))
        cell.set_part_pose(np.asarray(truth["T_cf_w"], dtype=float))
    stops = {int(k): np.asarray(T, dtype=float) for k, T in truth["stops"].items()}  # type: ignore[union-attr]
    current = int(truth["in_position"])  # type: ignore[call-overload]
    for number in sorted(stops, key=lambda k: k == current):  # the current stop last: it sets current_pose
        if 1 <= number <= cell.n_measuring_poses:  # not the base-calibration poses (101..): no camera pose
            cell.set_actual_flange_pose(number - 1, stops[number])
    return current


def file_mtime(path: Path) -> int:
    try:
        return path.stat().st_mtime_ns
    except OSError:
        return -1
