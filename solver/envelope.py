"""The part's deviation envelope: one definition for the planner, the simulated part supply, the offset
check and the measurement record.

A part lies off its reference by ``T_w0_w`` (the part in the frame of the reference part). The envelope
describes that displacement about one point of the part, ``about_w`` (part frame; default: the featured
holes' centroid):

- the rotation: the rotation vector ``r`` of ``R_w0_w``, per axis of the reference part frame (each within
  +- ``rotation_deg``) and its angle ``|r|`` (within ``total_deg``, default the norm of the per-axis limits);
- the translation of that point, ``t = T_w0_w a - a``: per axis (within +- ``translation_mm``) and in total
  (``|t|`` within ``total_mm``, default the norm of the per-axis limits).

So ``T_w0_w = [R(r) | a - R(r) a + t]`` (:func:`deviation_transform`). With the default totals every part
inside the per-axis box is inside the envelope; smaller totals cut the box's corners off. The grasp point is
where the predicted sigma is judged, not where the envelope is.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from monoguide.solver import frames
from monoguide.solver.errors import OffsetOutOfEnvelope

AXES = ("x", "y", "z")
MAX_DRAWS = 10_000  # attempts of one draw inside the totals before the envelope is called too thin to sample

Vector3 = tuple[float, float, float]


@dataclass(frozen=True)
class DeviationEnvelope:
    """How far a part may lie off its reference (the module's definition).

    translation_mm : (3,) +- mm per axis of the reference part frame, the shift of ``about_w``
    rotation_deg   : (3,) +- deg per axis, the components of the rotation vector
    about_w        : (3,) mm in the part frame, or None: the featured holes' centroid
    total_mm, total_deg : the shift's length and the rotation angle in total, or None: the norms of the
                     per-axis limits
    """

    translation_mm: Vector3 = (50.0, 50.0, 50.0)
    rotation_deg: Vector3 = (5.0, 5.0, 5.0)
    about_w: Vector3 | None = None
    total_mm: float | None = None
    total_deg: float | None = None

    def __post_init__(self) -> None:
        for name in ("translation_mm", "rotation_deg", "about_w"):
            value = getattr(self, name)
            if value is None:
                continue
            vector = tuple(float(v) for v in value)
            if len(vector) != 3 or not all(math.isfinite(v) for v in vector):
                raise ValueError(f"envelope {name}: expected 3 finite numbers (x, y, z), got {value!r}")
            if name != "about_w" and min(vector) < 0:
                raise ValueError(f"envelope {name}: expected +- limits >= 0, got {list(vector)}")
            object.__setattr__(self, name, vector)
        for name in ("total_mm", "total_deg"):
            value = getattr(self, name)
            if value is not None and (not math.isfinite(float(value)) or float(value) <= 0):
                raise ValueError(f"envelope {name}: expected a finite limit > 0, got {value!r}")

    @property
    def limit_mm(self) -> float:
        """The shift of ``about_w`` in total, mm: ``total_mm`` or the norm of the per-axis limits."""
        return float(np.linalg.norm(self.translation_mm)) if self.total_mm is None else float(self.total_mm)

    @property
    def limit_deg(self) -> float:
        """The rotation angle in total, deg: ``total_deg`` or the norm of the per-axis limits."""
        return float(np.linalg.norm(self.rotation_deg)) if self.total_deg is None else float(self.total_deg)

    @property
    def centre_w(self) -> Vector3 | None:
        """``about_w`` under the name it had before the envelope was one definition (``daemon/cycle`` reads it)."""
        return self.about_w

    def about(self, points_w: np.ndarray) -> np.ndarray:
        """The envelope's point (3,): ``about_w``, or the centroid of the featured holes ``points_w`` (n, 3)."""
        if self.about_w is not None:
            return np.asarray(self.about_w, dtype=float)
        return np.asarray(points_w, dtype=float).reshape(-1, 3).mean(axis=0)

    def at(self, points_w: np.ndarray) -> DeviationEnvelope:
        """This envelope with its point resolved for the part whose holes are ``points_w`` (n, 3)."""
        return DeviationEnvelope(self.translation_mm, self.rotation_deg, tuple(float(v) for v in self.about(points_w)),
                                 self.total_mm, self.total_deg)

    def describe(self) -> str:
        t = "/".join(f"{v:g}" for v in self.translation_mm)
        r = "/".join(f"{v:g}" for v in self.rotation_deg)
        return f"±{t} mm, ±{r}° (in total {self.limit_mm:.4g} mm, {self.limit_deg:.4g}°)"


def deviation_transform(rotvec_rad: np.ndarray, translation_mm: np.ndarray, about_w: np.ndarray) -> np.ndarray:
    """``T_w0_w`` (4, 4) of a part turned by ``rotvec_rad`` (3,) about ``about_w`` (3,) and that point shifted
    by ``translation_mm`` (3,), all in the reference part's frame."""
    R = frames.rotvec_to_matrix(np.asarray(rotvec_rad, dtype=float))
    a = np.asarray(about_w, dtype=float)
    return frames.make_T(R, a - R @ a + np.asarray(translation_mm, dtype=float))


def deviation_about(T_w0_w: np.ndarray, about_w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The inverse of :func:`deviation_transform`: (rotation vector (3,) deg, shift of ``about_w`` (3,) mm),
    both along the axes of the reference part frame, of the part ``T_w0_w`` (4, 4)."""
    a = np.asarray(about_w, dtype=float)
    rotvec = frames.matrix_to_rotvec(np.asarray(T_w0_w, dtype=float)[:3, :3])
    return np.degrees(rotvec), T_w0_w[:3, :3] @ a + T_w0_w[:3, 3] - a


def draw_deviation(rng: np.random.Generator, envelope: DeviationEnvelope, points_w: np.ndarray) -> np.ndarray:
    """``T_w0_w`` (4, 4) of a part drawn uniformly inside ``envelope`` (the part's holes ``points_w`` (n, 3)
    resolve its point): the shift, then the rotation, uniform per axis, drawn again while outside the totals
    (never with the default totals, so their stream is one shift and one rotation per part)."""
    box = np.asarray(envelope.translation_mm, dtype=float)
    turn = np.asarray(envelope.rotation_deg, dtype=float)
    for _ in range(MAX_DRAWS):
        t = rng.uniform(-1.0, 1.0, 3) * box
        r = rng.uniform(-1.0, 1.0, 3) * turn
        if np.linalg.norm(t) <= envelope.limit_mm and np.linalg.norm(r) <= envelope.limit_deg:
            return deviation_transform(np.radians(r), t, envelope.about(points_w))
    raise ValueError(f"envelope {envelope.describe()}: its totals leave too little of the per-axis box to draw in")


def check_deviation(envelope: DeviationEnvelope, rotation_deg: np.ndarray, shift_mm: np.ndarray,
                    about_w: np.ndarray) -> None:
    """Refuse (:class:`OffsetOutOfEnvelope`) a displacement outside ``envelope``, naming the axis and the values:
    not finite; the shift of ``about_w`` (3,) per axis ``shift_mm`` (3,), the rotation vector per axis
    ``rotation_deg`` (3,) (both along the reference part frame's axes); then their totals."""
    rotation, shift = np.asarray(rotation_deg, dtype=float), np.asarray(shift_mm, dtype=float)
    if not (np.all(np.isfinite(rotation)) and np.all(np.isfinite(shift))):
        raise OffsetOutOfEnvelope(f"the displacement is not finite (shift {shift}, rotation {rotation})")
    where = f"of the reference part frame at {_fmt(about_w)} mm of the part"
    for axis, value, limit in zip(AXES, shift, envelope.translation_mm, strict=True):
        if abs(value) > limit:
            raise OffsetOutOfEnvelope(f"the part lies {value:+.2f} mm off along {axis} {where}; the envelope allows "
                                      f"±{limit:g} mm: nothing is written")
    for axis, value, limit in zip(AXES, rotation, envelope.rotation_deg, strict=True):
        if abs(value) > limit:
            raise OffsetOutOfEnvelope(f"the part is turned {value:+.3f} deg about {axis} of the reference part frame; "
                                      f"the envelope allows ±{limit:g} deg: nothing is written")
    length, angle = float(np.linalg.norm(shift)), float(np.linalg.norm(rotation))
    if length > envelope.limit_mm:
        raise OffsetOutOfEnvelope(f"the part lies {length:.2f} mm off in total (x, y, z {_fmt(shift)} mm {where}); "
                                  f"the envelope allows {envelope.limit_mm:.4g} mm: nothing is written")
    if angle > envelope.limit_deg:
        raise OffsetOutOfEnvelope(f"the part is turned {angle:.3f} deg in total (about x, y, z {_fmt(rotation, 3)} deg "
                                  f"of the reference part frame); the envelope allows {envelope.limit_deg:.4g} deg: "
                                  "nothing is written")


def _fmt(v: np.ndarray, decimals: int = 2) -> str:
    return "(" + ", ".join(f"{float(x):.{decimals}f}" for x in v) + ")"
