"""Verification (step 6) and accuracy validation (step 7, paper Sec. 5.4, Table 3, Eq. 32).

Step 6: repeated measurements of the reference part give the cell's repeatability (per-axis standard
deviation of the measured pose, and the largest excursion from the mean), shown beside the planner's
predicted sigma. Step 7: a part in several poses; its displacement from the reference measured by the tracker
(featured holes) and by the camera; per pose the Euler angles (ψ about x, θ about y, φ about z, with
``R = Rz(φ) Ry(θ) Rx(ψ)``), the translation x y z, their differences Δ = camera - tracker, dR and dT (Eq. 32);
over all poses the RMS of dR and dT, and a verdict against the cell's tolerance.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from monoguide.solver.calibration.averaging import mean_pose
from monoguide.solver.calibration.errors import CalibrationTooFewViews
from monoguide.solver.frames import matrix_to_rotvec


def euler_xyz_deg(R: np.ndarray) -> np.ndarray:
    """(ψ, θ, φ) in degrees of ``R = Rz(φ) Ry(θ) Rx(ψ)`` (rotations about x, y, z: Table 3's angles)."""
    theta = math.asin(max(-1.0, min(1.0, -float(R[2, 0]))))
    psi = math.atan2(float(R[2, 1]), float(R[2, 2]))
    phi = math.atan2(float(R[1, 0]), float(R[0, 0]))
    return np.degrees([psi, theta, phi])


def euler_xyz_to_matrix(psi_deg: float, theta_deg: float, phi_deg: float) -> np.ndarray:
    """Inverse of :func:`euler_xyz_deg`."""
    a, b, c = (math.radians(v) for v in (psi_deg, theta_deg, phi_deg))
    Rx = np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])
    Ry = np.array([[math.cos(b), 0, math.sin(b)], [0, 1, 0], [-math.sin(b), 0, math.cos(b)]])
    Rz = np.array([[math.cos(c), -math.sin(c), 0], [math.sin(c), math.cos(c), 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


@dataclass(frozen=True)
class Repeatability:
    """Repeated measurements of one pose: mean pose, per-axis standard deviation of the translation (mm, (3,))
    and of the rotation vector about the mean (deg, (3,)), the largest deviation from the mean (mm, deg)."""

    T_mean: np.ndarray
    sigma_mm: np.ndarray
    sigma_deg: np.ndarray
    max_dev_mm: float
    max_dev_deg: float
    n: int

    def as_dict(self) -> dict[str, object]:
        return {"n": self.n, "sigma_mm": self.sigma_mm.tolist(), "sigma_deg": self.sigma_deg.tolist(),
                "max_dev_mm": self.max_dev_mm, "max_dev_deg": self.max_dev_deg}


def repeatability(poses: Sequence[np.ndarray]) -> Repeatability:
    """Statistics of repeated measurements ``T`` (n, 4, 4) of the same (reference) part."""

    poses = np.asarray(poses, dtype=float).reshape(-1, 4, 4)
    if len(poses) < 2:
        raise CalibrationTooFewViews(f"repeatability: {len(poses)} measurement(s), need at least 2")
    m = mean_pose(poses)
    rot = np.array([np.degrees(matrix_to_rotvec(m.T[:3, :3].T @ T[:3, :3])) for T in poses])
    return Repeatability(m.T, poses[:, :3, 3].std(axis=0, ddof=1), rot.std(axis=0, ddof=1), float(m.dev_mm.max()),
                         float(m.dev_deg.max()), len(poses))


@dataclass(frozen=True)
class Table3Row:
    """One pose of Table 3: tracker (LT) and camera (Mono) displacement as (ψ θ φ deg, x y z mm), Δ, dR, dT."""

    lt: np.ndarray
    mono: np.ndarray

    @property
    def delta(self) -> np.ndarray:
        d = self.mono - self.lt
        d[:3] = (d[:3] + 180.0) % 360.0 - 180.0
        return d

    @property
    def dR_deg(self) -> float:
        return float(np.linalg.norm(self.delta[:3]))

    @property
    def dT_mm(self) -> float:
        return float(np.linalg.norm(self.delta[3:]))


@dataclass(frozen=True)
class Table3:
    """Table 3 with its summary: RMS of dR (deg) and dT (mm) over the poses, and the verdict against the
    tolerance (``passed`` is None without one)."""

    rows: tuple[Table3Row, ...]
    tolerance_deg: float | None = None
    tolerance_mm: float | None = None

    @property
    def rms_dR_deg(self) -> float:
        return float(np.sqrt(np.mean([r.dR_deg**2 for r in self.rows])))

    @property
    def rms_dT_mm(self) -> float:
        return float(np.sqrt(np.mean([r.dT_mm**2 for r in self.rows])))

    @property
    def passed(self) -> bool | None:
        if self.tolerance_deg is None or self.tolerance_mm is None:
            return None
        return all(r.dR_deg <= self.tolerance_deg and r.dT_mm <= self.tolerance_mm for r in self.rows)

    def as_dict(self) -> dict[str, object]:
        cols = ("psi_deg", "theta_deg", "phi_deg", "x_mm", "y_mm", "z_mm")
        return {"rows": [{"lt": dict(zip(cols, r.lt.tolist(), strict=True)),
                          "mono": dict(zip(cols, r.mono.tolist(), strict=True)),
                          "delta": dict(zip(cols, r.delta.tolist(), strict=True)), "dR_deg": r.dR_deg,
                          "dT_mm": r.dT_mm} for r in self.rows],
                "rms_dR_deg": self.rms_dR_deg, "rms_dT_mm": self.rms_dT_mm, "passed": self.passed}

    def markdown(self) -> str:
        """The table as the paper prints it (LT, Mono, Δ per pose), with the RMS line."""
        lines = ["|  | ψ (°) | θ (°) | φ (°) | dR (°) | x (mm) | y (mm) | z (mm) | dT (mm) |",
                 "| :-: | --: | --: | --: | --: | --: | --: | --: | --: |"]
        for r in self.rows:
            for label, v, dR, dT in (("LT", r.lt, "", ""), ("Mono", r.mono, "", ""),
                                     ("Δ", r.delta, f"{r.dR_deg:.5f}", f"{r.dT_mm:.4f}")):
                lines.append(f"| {label} | {v[0]:.5f} | {v[1]:.5f} | {v[2]:.5f} | {dR} | {v[3]:.3f} | {v[4]:.3f} | "
                             f"{v[5]:.3f} | {dT} |")
        lines.append(f"| RMS |  |  |  | {self.rms_dR_deg:.5f} |  |  |  | {self.rms_dT_mm:.4f} |")
        return "\n".join(lines)


def displacement_vector(T_disp: np.ndarray) -> np.ndarray:
    """(ψ θ φ deg, x y z mm) of a displacement (4, 4)."""
    return np.concatenate([euler_xyz_deg(T_disp[:3, :3]), T_disp[:3, 3]])


def table3(lt_displacements: Sequence[np.ndarray], mono_displacements: Sequence[np.ndarray], *,
           tolerance_deg: float | None = None, tolerance_mm: float | None = None) -> Table3:
    """Table 3 from the displacements of the part from its reference pose (4, 4) each, as the tracker (LT) and
    the camera (Mono) measured them, expressed in the same frame (the paper: the part frame WF of the reference,
    ``T_w0_w``)."""
    if len(lt_displacements) != len(mono_displacements) or not lt_displacements:
        raise CalibrationTooFewViews(f"table 3: {len(lt_displacements)} tracker and {len(mono_displacements)} camera "
                                     "displacements; need the same number, at least one")
    rows = tuple(Table3Row(displacement_vector(np.asarray(a, dtype=float)),
                           displacement_vector(np.asarray(b, dtype=float)))
                 for a, b in zip(lt_displacements, mono_displacements, strict=True))
    return Table3(rows, tolerance_deg, tolerance_mm)



