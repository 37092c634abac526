"""The cell configuration: one TOML file, typed and validated on load (:func:`load_cell_config`).

Sections: ``[cell]``, ``[camera]`` (+ ``[camera.intrinsics]``), ``[part]``, ``[reference]``,
``[[measuring_poses]]``, and the optional ``[tracker]``, ``[sim]``, ``[layout]``, ``[robot]``, ``[plc]``
(``docs/plc-interface.md``), ``[service]``, ``[checks]``, ``[cell_frame]``, ``[calibration_target]`` and
``[calibration]`` (the provenance ``monoguide calibrate`` writes, ``docs/calibration.md``). Matrices are 4x4
row-major lists, lengths in mm, angles in degrees. Relative paths are relative to the config file. The keys are
documented in ``docs/cell-config.md``.

Strict: a bad file raises a :class:`ConfigError` naming the key, the value and why; a required key that
is missing is :class:`ConfigMissingKey` (never a zero), an unknown key or section is
:class:`ConfigUnknownKey` / :class:`ConfigUnknownSection` with the closest known name. Every duration and
count has a documented range (``_bounds.BOUNDS``); names are non-empty and unique; hosts are addresses or host
names; a cell that runs cycles (it has ``[robot]`` or ``[plc]``) gives the pose solver the redundancy it needs
(:data:`MIN_OBSERVATIONS` hole images of at least three holes not on one line). A command that needs an
optional section asks for it with :func:`require_sections`.

Each section's frozen dataclass sits beside its reader ``read_name(t: ConfigTable)`` in the module of its kind
(``_camera``, ``_part``, ``_devices``, ``_service``, ``_sim``, ``_layout``, ``_calibration``); this one puts the
sections together and checks what spans them. A later issue adds its section in three steps: the dataclass and
its reader, an entry in :data:`OPTIONAL_SECTIONS` and a ``CellConfig`` field of the same name (``None`` when the
file has no such section).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from dataclasses import dataclass, replace
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from monoguide.daemon.config._calibration import (
    CalibrationTargetConfig,
    CellFrameConfig,
    cell_calibration_gap,
    part_calibration_gap,
    read_calibration,
    read_calibration_target,
    read_cell_frame,
)
from monoguide.daemon.config._camera import CameraConfig, read_camera
from monoguide.daemon.config._devices import PlcConfig, RobotConfig, TrackerConfig, read_plc, read_robot, read_tracker
from monoguide.daemon.config._file import read_config_toml
from monoguide.daemon.config._layout import LayoutConfig, read_layout
from monoguide.daemon.config._marks import MARKS_KEY, ReferenceMarkConfig, read_reference_marks, resolve_pose_marks
from monoguide.daemon.config._part import (
    MeasuringPose,
    PartConfig,
    ReferenceConfig,
    read_measuring_poses,
    read_part,
    read_reference,
)
from monoguide.daemon.config._parts import DEFAULT_PART_NAME, PartType, read_parts, single_part
from monoguide.daemon.config._reader import ConfigTable
from monoguide.daemon.config._service import ChecksConfig, ServiceConfig, read_checks, read_service
from monoguide.daemon.config._sim import SimConfig, read_sim
from monoguide.daemon.errors import ConfigMissingKey
from monoguide.drivers.errors import ConfigError
from monoguide.solver import frames
from monoguide.solver.consistency import MIN_OBSERVATIONS

COLLINEAR_MM = 1e-3  # holes within this of one line leave the rotation about it unsolved

REQUIRED_SECTIONS = ("cell", "camera", "part", "reference", "measuring_poses")  # the single-part form
PARTS_SECTIONS = ("cell", "camera", "parts", "measuring_poses")  # the form of several part types ([reference]: T_cf_b)

# name -> reader of the optional sections; each has a CellConfig field of the same name. Add yours here.
OPTIONAL_SECTIONS: dict[str, Callable[[ConfigTable], Any]] = {
    "tracker": read_tracker,
    "sim": read_sim,
    "layout": read_layout,
    "robot": read_robot,
    "plc": read_plc,
    "service": read_service,
    "checks": read_checks,
    "cell_frame": read_cell_frame,
    "calibration_target": read_calibration_target,
    "calibration": read_calibration,
}


@dataclass(frozen=True)
class CellConfig:
    path: Path
    name: str
    camera: CameraConfig
    part: PartConfig
    reference: ReferenceConfig
    measuring_poses: tuple[MeasuringPose, ...]
    # optional sections (see OPTIONAL_SECTIONS): None when the file has no such section
    tracker: TrackerConfig | None = None
    sim: SimConfig | None = None
    layout: LayoutConfig | None = None
    robot: RobotConfig | None = None
    plc: PlcConfig | None = None
    service: ServiceConfig | None = None
    checks: ChecksConfig | None = None
    cell_frame: CellFrameConfig | None = None
    calibration_target: CalibrationTargetConfig | None = None
    calibration: dict[str, Any] | None = None  # provenance written by `monoguide calibrate`, as read
    # the part type this config is the view of (part, reference, measuring_poses and layout are its), and all of them
    job: int = 1
    part_name: str = DEFAULT_PART_NAME
    parts: tuple[PartType, ...] = ()
    cell_poses: tuple[MeasuringPose, ...] = ()  # every measuring pose of the cell, in robot pose number order
    reference_marks: tuple[ReferenceMarkConfig, ...] = ()  # [[reference_marks]]: the cell's fixed marks

    @property
    def jobs(self) -> tuple[int, ...]:
        """The job numbers the PLC may ask for (register 1)."""
        return tuple(p.job for p in self.parts)

    def for_job(self, job: int) -> CellConfig:
        """The cell as part type ``job`` sees it: its holes, reference, measuring poses and layout (built at load,
        so a job switch costs a lookup); :class:`ConfigError` naming the jobs there are for any other."""
        try:
            return self._views[job]
        except KeyError:
            raise ConfigError(f"{self.path}: no part of job {job}; the cell's jobs are "
                              f"{', '.join(p.describe() for p in self.parts)}") from None

    @cached_property
    def _views(self) -> dict[int, CellConfig]:
        return {p.job: self if p.job == self.job else replace(
            self, part=p.part, reference=ReferenceConfig(p.T_cf_w0, self.reference.T_cf_b),
            measuring_poses=p.measuring_poses, layout=p.layout, job=p.job, part_name=p.name) for p in self.parts}

    def calibration_gap(self, job: int) -> str | None:
        """Why part type ``job`` is not calibrated in this calibrated cell (missing steps, or the cell recalibrated
        since), or ``None``: its jobs are refused with ``PART_NOT_CALIBRATED`` while there is one."""
        return part_calibration_gap(self.calibration, job, self.jobs)

    def cell_calibration_gap(self) -> str | None:
        """Why the cell's own calibration is incomplete in a calibrated cell (its reference marks never surveyed, or
        surveyed before the cell frame was redone), or ``None``: every job is refused with ``PART_NOT_CALIBRATED``
        while there is one."""
        return cell_calibration_gap(self.calibration, bool(self.reference_marks))

    def taught_flange_poses(self) -> tuple[np.ndarray, ...]:
        """``T_b_f`` of each measuring pose of this part type: as taught, else from its calibrated camera pose (empty
        when the config cannot say): the cycle measures the robot's stand-off from it."""
        return self._taught(self.measuring_poses)

    def cell_taught_flange_poses(self) -> tuple[np.ndarray, ...]:
        """``T_b_f`` of every measuring pose of the cell, in pose number order: the robot adapter checks each stop."""
        return self._taught(self.cell_poses)

    def _taught(self, poses: tuple[MeasuringPose, ...]) -> tuple[np.ndarray, ...]:
        return frames.taught_flange_poses(self.reference.T_cf_b, self.camera.T_f_c,
                                          [(p.T_b_f, p.T_cf_si) for p in poses])


def load_cell_config(path: str | os.PathLike[str]) -> CellConfig:
    """Read and validate a cell file; raises :class:`ConfigError` naming the key, the value and why."""
    path = Path(path)
    root = ConfigTable(read_config_toml(path), path)  # a regular file of at most 4 MiB, else refused unread
    # a misspelt section: not "missing"
    root.reject_unknown((*REQUIRED_SECTIONS, *PARTS_SECTIONS, *OPTIONAL_SECTIONS, MARKS_KEY))
    name = _cell_name(root.table("cell"))
    camera = read_camera(root.table("camera"))
    marks = read_reference_marks(root.tables(MARKS_KEY))
    if root.has("parts"):
        if root.has("part"):
            raise ConfigError(f"{path}: [part] and [[parts]]: give one [part] (job 1) or [[parts]], not both")
        reference = read_reference(root.optional_table("reference"), with_part=False)
        cell_poses = _with_marks(read_measuring_poses(root.tables("measuring_poses", required=True), reference, camera,
                                                      None), marks, path)
        parts = read_parts(root.tables("parts", required=True), cell_poses)
    else:
        part_table = root.table("part")
        part_name = part_table.text("name", DEFAULT_PART_NAME, nonempty=True)
        part = read_part(part_table)
        reference = read_reference(root.table("reference"))
        cell_poses = _with_marks(read_measuring_poses(root.tables("measuring_poses", required=True), reference, camera,
                                                      len(part.points_w)), marks, path)
        parts = (single_part(part_name, part, reference.T_cf_w0, cell_poses, None),)
    optional = {key: read(root.table(key)) if root.has(key) else None for key, read in OPTIONAL_SECTIONS.items()}
    parts = tuple(replace(p, layout=p.layout or optional["layout"]) for p in parts)
    first = parts[0]
    config = CellConfig(path, name, camera, first.part, ReferenceConfig(first.T_cf_w0, reference.T_cf_b),
                        first.measuring_poses, **{**optional, "layout": first.layout}, job=first.job,
                        part_name=first.name, parts=parts, cell_poses=cell_poses, reference_marks=marks)
    _check_backends(config)
    if config.robot is not None or config.plc is not None:  # a cell that runs cycles
        for job in config.jobs:
            _check_redundancy(config.for_job(job))
    return config


def _with_marks(poses: tuple[MeasuringPose, ...], marks: tuple[ReferenceMarkConfig, ...],
                path: Path) -> tuple[MeasuringPose, ...]:
    """Each pose's ``marks = [names]`` as indices into ``[[reference_marks]]`` (ConfigError naming an unknown one)."""
    return tuple(replace(p, marks=resolve_pose_marks(f"{path}: [[measuring_poses]] {p.name}", p.mark_names, marks))
                 for p in poses)


def require_sections(config: CellConfig, sections: Iterable[str], *, command: str) -> None:
    """Refuse a config without an optional section that ``monoguide <command>`` needs: :class:`ConfigMissingKey`
    naming the section and the command (``require_sections(cfg, ("robot", "plc"), command="run")``)."""
    for section in sections:
        if section not in OPTIONAL_SECTIONS:
            raise ValueError(f"{section!r} is not an optional section of the cell config: {sorted(OPTIONAL_SECTIONS)}")
        if getattr(config, section) is None:
            role = _SECTION_ROLES.get(section, section)
            raise ConfigMissingKey(f"{config.path}: [{section}]: missing, a section `monoguide {command}` needs "
                                   f"({role})")


# what each optional section is to a command that needs it (require_sections' message)
_SECTION_ROLES = {
    "robot": "the robot controller",
    "plc": "the line's PLC, a Modbus TCP server",
    "tracker": "the laser tracker",
    "sim": "the simulated cell",
    "layout": "what the measuring poses are planned for",
    "cell_frame": "the benchmark nests of the cell frame",
    "calibration_target": "the calibration target",
}


def _cell_name(t: ConfigTable) -> str:
    """``[cell]``: the cell's name, all the section holds."""
    name = t.text("name", nonempty=True)
    t.done()
    return name


def _check_backends(config: CellConfig) -> None:
    """Simulated back-ends need the ``[sim]`` section they are built from."""
    if config.camera.backend == "sim" and config.sim is None:
        raise ConfigError(f"{config.path}: [camera].backend = 'sim' needs a [sim] section")
    if config.tracker is not None and config.tracker.backend == "sim" and config.sim is None:
        raise ConfigError(f"{config.path}: [tracker].backend = 'sim' needs a [sim] section")
    if config.robot is not None and config.robot.simulated and config.sim is None:
        raise ConfigError(f"{config.path}: [robot].backend = {config.robot.backend!r} needs a [sim] section")


def _check_redundancy(config: CellConfig) -> None:
    """The measuring poses together give the pose solver what it needs: at least :data:`MIN_OBSERVATIONS` hole
    images (two equations each for the pose's six unknowns, and a degree of freedom left for the chi-square
    consistency check, solver/consistency.py) of at least three holes not on one line (otherwise the rotation
    about that line is not observed). Without it every cycle would fail at run time."""
    poses, names = config.measuring_poses, config.part.point_names
    seen = [(pose.name, j) for pose in poses for j in pose.points]
    holes = sorted({j for _, j in seen})
    where = f"{config.path}: [[measuring_poses]] {', '.join(p.name for p in poses)}"
    if len(config.parts) > 1:
        where = (f"{config.path}: [[parts]] job {config.job} ({config.part_name!r}): measuring_poses "
                 f"{', '.join(p.name for p in poses)}")
    m = len(seen)
    if m < MIN_OBSERVATIONS:
        images = ", ".join(f"{names[j]} in {pose}" for pose, j in seen)
        raise ConfigError(f"{where}: see {m} hole image(s) of [part] ({images}); the pose solver needs at least "
                          f"{MIN_OBSERVATIONS}: two equations per image for the pose's 6 unknowns leave 2 x {m} - 6 "
                          f"= {2 * m - 6} degrees of freedom, and its consistency check needs at least 1")
    if len(holes) < 3:
        raise ConfigError(f"{where}: see {len(holes)} distinct hole(s) of [part] ({', '.join(names[j] for j in holes)}"
                          f"); the pose needs at least 3 holes not on one line (about the line through them it "
                          f"cannot be solved)")
    P = config.part.points_w[holes]
    P = P - P.mean(axis=0)
    direction = np.linalg.svd(P)[2][0]
    off_line = np.linalg.norm(P - np.outer(P @ direction, direction), axis=1)
    if float(off_line.max()) <= COLLINEAR_MM:
        raise ConfigError(f"{where}: the holes they see ({', '.join(names[j] for j in holes)}) lie on one line "
                          f"(all within {COLLINEAR_MM:g} mm of it); the rotation about it cannot be solved")
