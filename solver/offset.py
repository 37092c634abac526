"""The base offset (Eq. 1-5): how the taught grasp path must move to fit the part as it lies.

Eq. 5 gives the part's displacement as ``D_s1 = T_s1_w @ inv(T_s1_w0)``, written in SF1 (the frame of
the camera at the first measuring pose). A robot applies an offset in its own base frame, so the
displacement is conjugated into BF with the calibrated ``T_b_s1``: ``D_b = T_b_s1 @ D_s1 @ inv(T_b_s1)``;
every taught target ``T_b_x`` then becomes ``D_b @ T_b_x``. ``D_s1`` itself is no base offset: its
rotation turns about the origin of SF1, metres from the part, so sent as one it misses the grasp.

How far the part lies off is judged by the part's :class:`~monoguide.solver.envelope.DeviationEnvelope`:
the rotation (per axis of the reference part frame and its angle) about the envelope's point ``about_w``
(default the holes' centroid) and the shift of that point (per axis and in total). The grasp point ``g_w``
is where the robot grips and where the shift is reported and the predicted sigma judged; it is not where
the envelope is. A roof turned 3 deg in place about its centroid moves its corner holes 60 mm but its
centroid not at all, and is accepted.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from monoguide.solver import frames
from monoguide.solver.envelope import DeviationEnvelope, check_deviation


def part_displacement(T_s1_w: np.ndarray, T_s1_w0: np.ndarray) -> np.ndarray:
    """Eq. 5: the displacement (4, 4) that carries the reference part onto the measured one, in SF1."""
    return T_s1_w @ frames.invert(T_s1_w0)


def base_offset(D_s1: np.ndarray, T_b_s1: np.ndarray) -> np.ndarray:
    """The displacement ``D_s1`` (4, 4) expressed in the robot base frame, given ``T_b_s1`` (4, 4)."""
    return T_b_s1 @ D_s1 @ frames.invert(T_b_s1)


@dataclass(frozen=True)
class PartDisplacement:
    """How the measured part lies relative to the reference: at the grasp point, and about the envelope's point.

    displacement_s1 : (4, 4) Eq. 5, in SF1
    grasp_point_w   : (3,) the grasp point in the part frame, mm
    grasp_shift_s1  : (3,) how far the grasp point moves, in SF1, mm
    grasp_shift_w0  : (3,) the same shift along the axes of the reference part frame, mm
    rotation_w0_deg : (3,) rotation vector of the displacement in the reference part frame, deg
    rotation_deg    : the rotation angle, deg
    base_offset     : (4, 4) the displacement in the robot base frame, or None without ``T_b_s1``
    about_w         : (3,) the envelope's point in the part frame, mm (what the envelope bounds the shift of)
    about_shift_w0  : (3,) how far that point moves, along the axes of the reference part frame, mm
    """

    displacement_s1: np.ndarray
    grasp_point_w: np.ndarray
    grasp_shift_s1: np.ndarray
    grasp_shift_w0: np.ndarray
    rotation_w0_deg: np.ndarray
    rotation_deg: float
    base_offset: np.ndarray | None
    about_w: np.ndarray
    about_shift_w0: np.ndarray

    @property
    def grasp_shift_mm(self) -> float:
        return float(np.linalg.norm(self.grasp_shift_s1))


def describe_displacement(
    T_s1_w: np.ndarray, T_s1_w0: np.ndarray, grasp_point_w: np.ndarray, about_w: np.ndarray,
    T_b_s1: np.ndarray | None = None,
) -> PartDisplacement:
    """The displacement of the part at ``T_s1_w`` (4, 4) from the reference ``T_s1_w0`` (4, 4): measured at
    ``grasp_point_w`` (3,) and about the envelope's point ``about_w`` (3,) (resolved:
    :meth:`DeviationEnvelope.about`); with ``T_b_s1`` (4, 4) also the base offset."""
    D_s1 = part_displacement(T_s1_w, T_s1_w0)
    R_w0_s1 = T_s1_w0[:3, :3].T
    rotvec_s1 = frames.matrix_to_rotvec(D_s1[:3, :3])
    shift_s1, about_shift_s1 = (_shift_s1(D_s1, T_s1_w0, point_w) for point_w in (grasp_point_w, about_w))
    return PartDisplacement(
        displacement_s1=D_s1,
        grasp_point_w=np.asarray(grasp_point_w, dtype=float).copy(),
        grasp_shift_s1=shift_s1,
        grasp_shift_w0=R_w0_s1 @ shift_s1,
        rotation_w0_deg=np.degrees(R_w0_s1 @ rotvec_s1),
        rotation_deg=math.degrees(float(np.linalg.norm(rotvec_s1))),
        base_offset=None if T_b_s1 is None else base_offset(D_s1, T_b_s1),
        about_w=np.asarray(about_w, dtype=float).copy(),
        about_shift_w0=R_w0_s1 @ about_shift_s1,
    )


def check_envelope(displacement: PartDisplacement, envelope: DeviationEnvelope) -> None:
    """Refuse (:class:`~monoguide.solver.errors.OffsetOutOfEnvelope`) a displacement outside ``envelope``,
    naming the axis and the values (:func:`~monoguide.solver.envelope.check_deviation`): the shift of the
    envelope's point and the rotation per axis of the reference part frame, then their totals. Nothing beyond
    the envelope may reach a robot. ``displacement`` must be described about the envelope's point (a
    :class:`ValueError` otherwise: a programming error, not a part off its place)."""
    d = displacement
    if envelope.about_w is not None and not np.allclose(d.about_w, envelope.about_w, atol=1e-9, rtol=0.0):
        raise ValueError(f"the displacement is described about {d.about_w.tolist()}, the envelope is about "
                         f"{list(envelope.about_w)}")
    check_deviation(envelope, d.rotation_w0_deg, d.about_shift_w0, d.about_w)


def _shift_s1(D_s1: np.ndarray, T_s1_w0: np.ndarray, point_w: np.ndarray) -> np.ndarray:
    """How far the reference part's point ``point_w`` (3,) moves under ``D_s1`` (4, 4), in SF1, mm."""
    p_s1 = T_s1_w0[:3, :3] @ np.asarray(point_w, dtype=float) + T_s1_w0[:3, 3]
    return D_s1[:3, :3] @ p_s1 + D_s1[:3, 3] - p_s1
