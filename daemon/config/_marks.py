"""``[[reference_marks]]``: the fixed marks of the cell (on the fixture or rack beside the part, surveyed once with
the laser tracker: ``monoguide calibrate``'s ``marks`` step), and which of them each measuring pose sees
(``[[measuring_poses]] marks``). With them every cycle measures where each view's camera stood (docs/cycle-marks.md).

A mark is a dark circle on a light ground (the hole finder finds it as it finds a hole), ``diameter_mm`` across,
lying in the plane through ``position_cf`` with normal ``normal_cf``. ``sigma_mm``: its survey's sigma per axis.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from monoguide.daemon.config._reader import ConfigTable
from monoguide.drivers.errors import ConfigError
from monoguide.solver.marks_problem import MARK_SIGMA_MM, ReferenceMark

MARKS_KEY = "reference_marks"


@dataclass(frozen=True)
class ReferenceMarkConfig:
    """One ``[[reference_marks]]`` entry."""

    name: str
    position_cf: np.ndarray  # (3,) mm, the mark's centre in the cell frame
    diameter_mm: float
    normal_cf: np.ndarray  # (3,) unit, the mark plane's normal (towards the cameras)
    sigma_mm: float = MARK_SIGMA_MM

    @property
    def radius_mm(self) -> float:
        return self.diameter_mm / 2.0

    def as_solver(self) -> ReferenceMark:
        return ReferenceMark(self.name, self.position_cf, self.sigma_mm)


def read_reference_marks(entries: list[ConfigTable]) -> tuple[ReferenceMarkConfig, ...]:
    marks: list[ReferenceMarkConfig] = []
    for t in entries:
        name = t.text("name", nonempty=True)
        if any(m.name == name for m in marks):
            raise ConfigError(f"{t.where}.name = {name!r}: another [[reference_marks]] has this name already")
        normal = t.vector("normal_cf", 3, np.array([0.0, 0.0, 1.0]))
        if float(np.linalg.norm(normal)) < 1e-9:
            raise ConfigError(f"{t.where}.normal_cf = {normal.tolist()}: expected a non-zero vector")
        marks.append(ReferenceMarkConfig(name, t.vector("position_cf", 3), t.number("diameter_mm", positive=True),
                                         normal / np.linalg.norm(normal),
                                         t.number("sigma_mm", MARK_SIGMA_MM, positive=True)))
        t.done()
    return tuple(marks)


def resolve_pose_marks(where: str, names: tuple[str, ...], marks: tuple[ReferenceMarkConfig, ...]) -> tuple[int, ...]:
    """The indices into ``marks`` of a measuring pose's ``marks = [...]``; :class:`ConfigError` naming an unknown
    or repeated mark."""
    known = [m.name for m in marks]
    out = []
    for name in names:
        if name not in known:
            listed = ", ".join(known) if known else "none: the file has no [[reference_marks]]"
            raise ConfigError(f"{where}.marks: {name!r} is not a [[reference_marks]] name (the marks are {listed})")
        if known.index(name) in out:
            raise ConfigError(f"{where}.marks = {list(names)}: {name!r} listed twice")
        out.append(known.index(name))
    return tuple(out)
