"""``[[parts]]``: the part types of a cell, each selected by the PLC's job number (register 1).

A part type has its job (1-65535, unique), its name, its featured holes, its grasp point, the reference part its
grasp path was taught on (``T_cf_w0``), its own ``[parts.layout]`` (what its measuring poses are planned for,
with its deviation envelope; the cell's ``[layout]`` when absent) and its views: which of the cell's
``[[measuring_poses]]`` see which of its holes, ``measuring_poses = { S1 = ["P1"], S5 = ["H1", "H2"] }``. The
cell's measuring poses are shared: two parts may use the same pose, each seeing its own holes from it. A pose's
robot pose number is its place in the cell's ``[[measuring_poses]]`` (the first is 1), the same for every part.

The older form — one ``[part]``, ``[reference] T_cf_w0`` and ``points`` in each ``[[measuring_poses]]`` — is read
as one part type, job 1, unchanged in meaning (:func:`single_part`).
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass, replace

import numpy as np

from monoguide.daemon.config._bounds import bounded_integer
from monoguide.daemon.config._layout import LayoutConfig, read_layout
from monoguide.daemon.config._part import MeasuringPose, PartConfig, read_part
from monoguide.daemon.config._reader import ConfigTable
from monoguide.drivers.errors import ConfigError

MAX_JOB = 65534  # PLC register 1 is a uint16; 0 is "no job", 65535 the check job
DEFAULT_PART_NAME = "part"  # the older single-part form's name when [part] gives none


@dataclass(frozen=True)
class PartType:
    """One part type: what the cycle measures, checks and offsets when the PLC asks for its job."""

    job: int
    name: str
    part: PartConfig
    T_cf_w0: np.ndarray  # the reference part its grasp path was taught on, in the cell frame
    measuring_poses: tuple[MeasuringPose, ...]  # its views: the cell's poses, ``points`` = indices of its holes
    layout: LayoutConfig | None = None  # its own [parts.layout]; None: the cell's [layout]

    def describe(self) -> str:
        return f"job {self.job} ({self.name!r})"


def single_part(name: str, part: PartConfig, T_cf_w0: np.ndarray, poses: tuple[MeasuringPose, ...],
                layout: LayoutConfig | None) -> PartType:
    """The older form's one part: job 1, its poses the cell's poses."""
    return PartType(1, name, part, T_cf_w0, poses, layout)


def read_parts(entries: list[ConfigTable], cell_poses: tuple[MeasuringPose, ...]) -> tuple[PartType, ...]:
    """Each ``[[parts]]`` entry, checked on its own and against the others (jobs and names unique)."""
    parts: list[PartType] = []
    for t in entries:
        job = bounded_integer(t, "job")
        name = t.text("name", nonempty=True)
        where = f"{t.where} (job {job}, {name!r})"
        for other in parts:
            if other.job == job:
                raise ConfigError(f"{where}.job = {job}: already the job of [[parts]] {other.name!r}; the PLC selects "
                                  "a part by its job, so each part has its own")
            if other.name == name:
                raise ConfigError(f"{where}.name = {name!r}: already the name of [[parts]] job {other.job}")
        T_cf_w0 = t.matrix("T_cf_w0")
        views = _read_views(t, where, cell_poses)
        layout = read_layout(t.table("layout")) if t.has("layout") else None
        part = read_part(t)  # last: it calls t.done(), refusing every key not read above
        parts.append(PartType(job, name, part, T_cf_w0, _resolve_views(views, part, where, cell_poses), layout))
    return tuple(parts)


def _read_views(t: ConfigTable, where: str, cell_poses: tuple[MeasuringPose, ...]) -> dict[str, list[str]]:
    t.known.add("measuring_poses")
    if "measuring_poses" not in t.raw:
        raise ConfigError(f"{where}.measuring_poses: missing; give the cell's poses that see this part's holes, "
                          f"e.g. measuring_poses = {{ {cell_poses[0].name} = [\"P1\"] }}")
    views = t.raw["measuring_poses"]
    if not isinstance(views, dict) or not views or not all(
            isinstance(v, list) and all(isinstance(h, str) for h in v) for v in views.values()):
        raise ConfigError(f"{where}.measuring_poses = {views!r}: expected a table of pose name = [hole names], "
                          "e.g. { S1 = [\"P1\"], S2 = [\"P2\", \"P3\"] }")
    return views


def _resolve_views(views: dict[str, list[str]], part: PartConfig, where: str,
                   cell_poses: tuple[MeasuringPose, ...]) -> tuple[MeasuringPose, ...]:
    """The part's views in the cell's pose order (the robot visits them as they stand in [[measuring_poses]])."""
    by_name = {pose.name: pose for pose in cell_poses}
    names = list(part.point_names)
    for pose_name, holes in views.items():
        if pose_name not in by_name:
            close = difflib.get_close_matches(pose_name, list(by_name), n=1)
            hint = f"did you mean {close[0]!r}?" if close else f"the cell's poses are {', '.join(by_name)}"
            raise ConfigError(f"{where}.measuring_poses.{pose_name}: no such [[measuring_poses]] in the cell; {hint}")
        if not holes:
            raise ConfigError(f"{where}.measuring_poses.{pose_name} = []: a view sees at least one featured hole")
        for hole in holes:
            if hole not in names:
                close = difflib.get_close_matches(hole, names, n=1)
                hint = f"did you mean {close[0]!r}?" if close else f"its holes are {', '.join(names)}"
                raise ConfigError(f"{where}.measuring_poses.{pose_name} = {holes}: {hole!r} is not a hole of this "
                                  f"part (point_names); {hint}")
        if twice := sorted({h for h in holes if holes.count(h) > 1}):
            raise ConfigError(f"{where}.measuring_poses.{pose_name} = {holes}: {twice} listed twice (one image of a "
                              "hole per view)")
    return tuple(replace(pose, points=tuple(names.index(h) for h in views[pose.name]))
                 for pose in cell_poses if pose.name in views)
