"""The base offset (Eq. 1-5): how the taught grasp path must move to fit the part as it lies.

Eq. 5 gives the part's displacement as ``D_s1 = T_s1_w @ inv(T_s1_w0)``, written in SF1 (the frame of
the camera at the first measuring pose). A robot applies an offset in its own base frame, so the
displacement is conjugated into BF with the calibrated ``T_b_s1``: ``D_b = T_b_s1 @ D_s1 @ inv(T_b_s1)``;
every taught target ``T_b_x`` then becomes ``D_b @ T_b_x``. ``D_s1`` itself is no base offset: its
rotation turns about the origin of SF1, metres from the part, so sent as one it misses the grasp.

How far the part lies off is judged where the robot grips it: the grasp point ``g_w`` (part frame;
by default the featured points' centroid). Its shift and the rotation angle are compared with the
:class:`Envelope`, per axis of the reference part frame and in total. A roof turned 3 deg in place
about its centre moves its corner holes 60 mm but its grasp point not at all, and is accepted.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from monoguide.solver import frames
from monoguide.solver.errors import OffsetOutOfEnvelope

AXES = ("x", "y", "z")


def part_displacement(T_s1_w: np.ndarray, T_s1_w0: np.ndarray) -> np.ndarray:
    """Eq. 5: the displacement (4, 4) that carries the reference part onto the measured one, in SF1."""
    return T_s1_w @ frames.invert(T_s1_w0)


def base_offset(D_s1: np.ndarray, T_b_s1: np.ndarray) -> np.ndarray:
    """The displacement ``D_s1`` (4, 4) expressed in the robot base frame, given ``T_b_s1`` (4, 4)."""
    return T_b_s1 @ D_s1 @ frames.invert(T_b_s1)


@dataclass(frozen=True)
class Envelope:
    """How far a part may lie from the reference before monoguide refuses to correct for it.

    ``max_mm`` bounds the grasp point's shift in total, ``max_deg`` the rotation angle; ``axis_mm`` and
    ``axis_deg`` (3 each, default: the totals) bound the shift and the rotation-vector components per
    axis of the reference part frame.
    """

    max_mm: float = 50.0
    max_deg: float = 5.0
    axis_mm: tuple[float, float, float] | None = None
    axis_deg: tuple[float, float, float] | None = None

    def __post_init__(self) -> None:
        limits = [self.max_mm, self.max_deg, *(self.axis_mm or ()), *(self.axis_deg or ())]
        if any(not math.isfinite(v) or v <= 0 for v in limits):
            raise ValueError(f"envelope limits must be positive and finite, got {self}")
        for name in ("axis_mm", "axis_deg"):
            value = getattr(self, name)
            if value is not None and len(value) != 3:
                raise ValueError(f"envelope {name}: expected 3 limits (x, y, z), got {value!r}")

    @property
    def per_axis_mm(self) -> tuple[float, float, float]:
        return self.axis_mm or (self.max_mm,) * 3

    @property
    def per_axis_deg(self) -> tuple[float, float, float]:
        return self.axis_deg or (self.max_deg,) * 3


@dataclass(frozen=True)
class PartDisplacement:
    """How the measured part lies relative to the reference, described at the grasp point.

    displacement_s1 : (4, 4) Eq. 5, in SF1
    grasp_point_w   : (3,) the grasp point in the part frame, mm
    grasp_shift_s1  : (3,) how far the grasp point moves, in SF1, mm
    grasp_shift_w0  : (3,) the same shift along the axes of the reference part frame, mm
    rotation_w0_deg : (3,) rotation vector of the displacement in the reference part frame, deg
    rotation_deg    : the rotation angle, deg
    base_offset     : (4, 4) the displacement in the robot base frame, or None without ``T_b_s1``
    """

    displacement_s1: np.ndarray
    grasp_point_w: np.ndarray
    grasp_shift_s1: np.ndarray
    grasp_shift_w0: np.ndarray
    rotation_w0_deg: np.ndarray
    rotation_deg: float
    base_offset: np.ndarray | None

    @property
    def grasp_shift_mm(self) -> float:
        return float(np.linalg.norm(self.grasp_shift_s1))


def describe_displacement(
    T_s1_w: np.ndarray, T_s1_w0: np.ndarray, grasp_point_w: np.ndarray, T_b_s1: np.ndarray | None = None
) -> PartDisplacement:
    """The displacement of the part at ``T_s1_w`` (4, 4) from the reference ``T_s1_w0`` (4, 4), measured at
    ``grasp_point_w`` (3,); with ``T_b_s1`` (4, 4) also the base offset."""
    D_s1 = part_displacement(T_s1_w, T_s1_w0)
    g_s1 = T_s1_w0[:3, :3] @ grasp_point_w + T_s1_w0[:3, 3]
    shift_s1 = D_s1[:3, :3] @ g_s1 + D_s1[:3, 3] - g_s1
    R_w0_s1 = T_s1_w0[:3, :3].T
    rotvec_s1 = frames.matrix_to_rotvec(D_s1[:3, :3])
    return PartDisplacement(
        displacement_s1=D_s1,
        grasp_point_w=np.asarray(grasp_point_w, dtype=float).copy(),
        grasp_shift_s1=shift_s1,
        grasp_shift_w0=R_w0_s1 @ shift_s1,
        rotation_w0_deg=np.degrees(R_w0_s1 @ rotvec_s1),
        rotation_deg=math.degrees(float(np.linalg.norm(rotvec_s1))),
        base_offset=None if T_b_s1 is None else base_offset(D_s1, T_b_s1),
    )


def check_envelope(displacement: PartDisplacement, envelope: Envelope) -> None:
    """Refuse (:class:`OffsetOutOfEnvelope`) a displacement outside ``envelope``, naming the axis and
    the values: the grasp point's shift and the rotation per axis of the reference part frame, then
    their totals. Nothing beyond the envelope may reach a robot."""
    d = displacement
    values = [*d.grasp_shift_w0, *d.rotation_w0_deg, d.grasp_shift_mm, d.rotation_deg]
    if not all(math.isfinite(float(v)) for v in values):
        raise OffsetOutOfEnvelope(
            f"the displacement is not finite (shift {d.grasp_shift_w0}, rotation {d.rotation_w0_deg})"
        )
    where = f"at the grasp point {_fmt(d.grasp_point_w)} mm"
    for axis, shift, limit in zip(AXES, d.grasp_shift_w0, envelope.per_axis_mm, strict=True):
        if abs(shift) > limit:
            raise OffsetOutOfEnvelope(
                f"the part lies {shift:+.2f} mm off along {axis} of the reference part frame {where}; the "
                f"envelope allows ±{limit:g} mm: nothing is written"
            )
    for axis, angle, limit in zip(AXES, d.rotation_w0_deg, envelope.per_axis_deg, strict=True):
        if abs(angle) > limit:
            raise OffsetOutOfEnvelope(
                f"the part is turned {angle:+.3f} deg about {axis} of the reference part frame; the envelope "
                f"allows ±{limit:g} deg: nothing is written"
            )
    if d.grasp_shift_mm > envelope.max_mm:
        raise OffsetOutOfEnvelope(
            f"the part lies {d.grasp_shift_mm:.2f} mm off {where} (x, y, z {_fmt(d.grasp_shift_w0)} mm in the "
            f"reference part frame); the envelope allows {envelope.max_mm:g} mm: nothing is written"
        )
    if d.rotation_deg > envelope.max_deg:
        raise OffsetOutOfEnvelope(
            f"the part is turned {d.rotation_deg:.3f} deg (about x, y, z {_fmt(d.rotation_w0_deg, 3)} deg of the "
            f"reference part frame); the envelope allows {envelope.max_deg:g} deg: nothing is written"
        )


def _fmt(v: np.ndarray, decimals: int = 2) -> str:
    return "(" + ", ".join(f"{float(x):.{decimals}f}" for x in v) + ")"
