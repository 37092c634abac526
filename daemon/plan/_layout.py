"""The cell config's side of ``monoguide plan --layout``: the layout request a cell file describes, its
current measuring poses, and a copy of the file with planned ones (``--write``).

Frames: the planner works in the reference part's frame (``T_w0_si``); the config keeps the cell frame,
``T_cf_si = T_cf_w0 @ T_w0_si``. When the file's measuring poses give taught flange poses (``T_b_f``), the
copy gives them too, ``T_b_f = inv(T_cf_b) @ T_cf_si @ inv(T_f_c)``, so the two cannot disagree.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import tomlkit
import tomlkit.exceptions

from monoguide.daemon.config import CellConfig, LayoutConfig, load_cell_config, read_config_text
from monoguide.drivers.atomic_file import write_atomic
from monoguide.drivers.errors import ConfigError
from monoguide.drivers.toml_format import commented, inline_table, matrix, replace_section
from monoguide.solver.frames import compose, invert, transform_points
from monoguide.solver.planning import LayoutAssessment, LayoutRequest, ReachRegion

WRITE_TOL_MM = 1e-6  # a written pose must read back to within this (and the rotation to 1e-9)


@dataclass(frozen=True)
class CellLayout:
    """What the cell config says about its layout: the request to plan for and the current poses.

    T_w0_si : (k, 4, 4) the configured measuring poses in the reference part's frame; observed: (view, point)
    """

    request: LayoutRequest
    T_w0_si: tuple[np.ndarray, ...]
    observed: tuple[tuple[int, int], ...]
    names: tuple[str, ...]


def cell_layout(config: CellConfig, sigma_px: float | None = None) -> CellLayout:
    """The layout request of a cell file (``[part]``, ``[camera]``, ``[layout]``) and its current poses."""
    layout = config.layout or LayoutConfig()
    constraints = layout.constraints
    T_w0_cf = invert(config.reference.T_cf_w0)
    if layout.reach_radius_mm is not None:
        if config.reference.T_cf_b is None:
            raise ConfigError(f"{config.path}: [layout] reach_radius_mm needs [reference] T_cf_b (the robot base)")
        base_w = transform_points(T_w0_cf, config.reference.T_cf_b[:3, 3].reshape(1, 3))[0]
        T_f_c = config.camera.T_f_c if config.camera.T_f_c is not None else np.eye(4)
        flange_c = invert(T_f_c)[:3, 3]
        reach = ReachRegion(tuple(base_w), layout.reach_radius_mm, tuple(flange_c))
        constraints = type(constraints)(constraints.standoff_mm, constraints.max_view_angle_deg,
                                        constraints.margin_px, constraints.depth_of_field_mm, reach)
    request = LayoutRequest(
        camera=config.camera.intrinsics,
        points_w=config.part.points_w,
        envelope=layout.envelope,
        constraints=constraints,
        normals_w=config.part.normals_w,
        grasp_point_w=config.part.grasp_point_w,
        sigma_px=layout.sigma_px if sigma_px is None else sigma_px,
        repeatability_mm=layout.repeatability_mm,
        repeatability_deg=layout.repeatability_deg,
        point_names=config.part.point_names,
        T_f_c=config.camera.T_f_c,  # the repeatability acts at the flange (None: about the camera's centre)
    )
    poses = tuple(compose(T_w0_cf, p.T_cf_si) for p in config.measuring_poses)
    observed = tuple((i, point) for i, p in enumerate(config.measuring_poses) for point in p.points)
    return CellLayout(request, poses, observed, tuple(p.name for p in config.measuring_poses))


def planned_pose_names(config: CellConfig, n_points: int) -> tuple[str, ...]:
    """Names for the planned poses (pose i sees point i): the configured pose that sees only point i keeps
    its name, the others are ``S1``, ``S2``, ..."""
    names = []
    for i in range(n_points):
        same = [p.name for p in config.measuring_poses if p.points == (i,)]
        names.append(same[0] if same else f"S{i + 1}")
    return tuple(names)


def write_config_with_layout(config: CellConfig, plan: LayoutAssessment, out: Path, note: str) -> Path:
    """Write a copy of the cell file with the planned measuring poses in place of its ``[[measuring_poses]]``
    (everything else, comments included, as it was: the file is edited as a tomlkit document); read back and
    checked before it replaces ``out``."""
    try:
        doc = tomlkit.parse(read_config_text(config.path))
    except tomlkit.exceptions.TOMLKitError as exc:
        raise ConfigError(f"{config.path}: cannot read it to write the planned poses: {exc}") from exc
    names = planned_pose_names(config, len(plan.T_w0_si))
    with_flange = any(p.T_b_f is not None for p in config.measuring_poses)
    T_cf_si = [compose(config.reference.T_cf_w0, T) for T in plan.T_w0_si]
    parts_form = "parts" in doc
    poses = tomlkit.aot()
    for i, (T, name) in enumerate(zip(T_cf_si, names, strict=True)):
        pose = tomlkit.table()
        pose.update({"name": commented(tomlkit.item(name), note), **({} if parts_form else {"points": [i]}),
                     "T_cf_si": matrix(T)})
        if with_flange and config.reference.T_cf_b is not None and config.camera.T_f_c is not None:
            pose["T_b_f"] = matrix(compose(invert(config.reference.T_cf_b), T, invert(config.camera.T_f_c)))
        poses.append(pose)
    if parts_form:
        _replace_part_poses(doc, config, names, poses)
    else:
        replace_section(doc, "measuring_poses", poses)
    return write_atomic(Path(out), doc.as_string(), durable=True,
                        before_replace=lambda written: _check_written(
                            load_cell_config(written).for_job(config.job), T_cf_si, Path(out)))


# --- private -----------------------------------------------------------------------------------


def _replace_part_poses(doc: tomlkit.TOMLDocument, config: CellConfig, names: tuple[str, ...], poses: Any) -> None:
    """A cell of ``[[parts]]``: the planned part type's poses replace the cell's poses of the same name (a new name
    is added at the end of ``[[measuring_poses]]``, with the next robot pose number), and its ``measuring_poses``
    become one planned pose per hole; the other part types and the poses only they use stay as they were."""
    cell_poses = doc["measuring_poses"]
    where = {entry.get("name"): k for k, entry in enumerate(cell_poses)}
    for name, pose in zip(names, poses, strict=True):
        if name in where:
            entry = cell_poses[where[name]]
            for key in ("T_cf_si", "T_b_f"):
                if key in entry and key not in pose:
                    del entry[key]
            for key, value in pose.items():
                entry[key] = value
        else:
            cell_poses.append(pose)
    part = next(entry for entry in doc["parts"] if entry.get("job") == config.job)
    holes = config.part.point_names
    part["measuring_poses"] = inline_table({name: [holes[i]] for i, name in enumerate(names)})


def _check_written(written: CellConfig, T_cf_si: list[np.ndarray], out: Path) -> None:
    got = [p.T_cf_si for p in written.measuring_poses]
    if len(got) != len(T_cf_si) or any(
        np.max(np.abs(a[:3, 3] - b[:3, 3])) > WRITE_TOL_MM or np.max(np.abs(a[:3, :3] - b[:3, :3])) > 1e-9
        for a, b in zip(got, T_cf_si, strict=False)
    ):
        raise ConfigError(f"{out}: the written measuring poses do not read back as planned; nothing written")
