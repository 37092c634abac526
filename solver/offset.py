"""The base offset (Eq. 1-5): how the taught grasp path must move to fit the part as it lies.

Eq. 5 gives the offset as ``T_s1_w @ inv(T_s1_w0)``: the part's displacement, written in SF1. A robot
applies it in its own base frame, so it is conjugated into BF with the calibrated ``T_b_s1``:
``D_b = T_b_s1 @ D_s1 @ inv(T_b_s1)``; every taught target ``T_b_x`` then becomes ``D_b @ T_b_x``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from monoguide.solver import frames
from monoguide.solver.errors import OffsetOutOfEnvelope


def part_displacement(T_s1_w: np.ndarray, T_s1_w0: np.ndarray) -> np.ndarray:
    """Eq. 5: the displacement (4, 4) that carries the reference part onto the measured one, in SF1."""
    return T_s1_w @ frames.invert(T_s1_w0)


def base_offset(D_s1: np.ndarray, T_b_s1: np.ndarray) -> np.ndarray:
    """The displacement ``D_s1`` (4, 4) expressed in the robot base frame, given ``T_b_s1`` (4, 4)."""
    return T_b_s1 @ D_s1 @ frames.invert(T_b_s1)


@dataclass(frozen=True)
class Envelope:
    """How far a part may lie from the reference before monoguide refuses to correct for it."""

    max_mm: float = 50.0
    max_deg: float = 5.0


def check_envelope(D: np.ndarray, points: np.ndarray, envelope: Envelope) -> tuple[float, float]:
    """Refuse a displacement outside the envelope; return its (angle deg, largest point shift mm).

    D      : (4, 4) displacement in some frame
    points : (n, 3) the featured points at their reference position, in the same frame; the shift is
             the largest distance any of them moves (so it does not depend on where the frame is).
    """
    angle = frames.rotation_angle_deg(D[:3, :3])
    moved = frames.transform_points(D, points) - points
    shift = float(np.max(np.linalg.norm(moved, axis=1)))
    if not (np.isfinite(angle) and np.isfinite(shift)):
        raise OffsetOutOfEnvelope(f"the displacement is not finite (angle {angle}, shift {shift})")
    if angle > envelope.max_deg or shift > envelope.max_mm:
        raise OffsetOutOfEnvelope(
            f"part displaced by {angle:.3f} deg and up to {shift:.2f} mm at a featured point; "
            f"the envelope allows {envelope.max_deg:g} deg and {envelope.max_mm:g} mm: nothing is written"
        )
    return angle, shift
