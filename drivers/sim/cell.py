"""The simulated cell's one truth: where the part, the robot, the camera and every SMR really are.

Every simulated device reads a :class:`SimCell`: the camera renders the part at the robot's actual pose,
the tracker measures the SMR nests the cell lists. Because the truth is known, a simulated run can say
how far any result is from the perfect one (:meth:`SimCell.T_s1_w_true`). Everything random is drawn
from the cell's seeded generator unless a generator is passed in.

The cell's fixed reference marks (:class:`SimMark`, the config's ``[[reference_marks]]``) are seen by both: the
camera renders each as a dark disc where it lies, unless the current part's sheet (its ``outline_w``) hides it
(:mod:`monoguide.drivers.sim.camera`), and each has a hidden-point SMR nest under its name for the tracker.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from monoguide.drivers.atomic_file import write_atomic
from monoguide.drivers.sim.target_renderer import base_calibration_poses
from monoguide.solver.calibration.intrinsics import CirclePlate
from monoguide.solver.calibration.target import TargetMarks, default_target_marks
from monoguide.solver.camera import CameraModel
from monoguide.solver.frames import compose, invert, make_T, rotvec_to_matrix, transform_points

TARGETS_FORMAT = "monoguide.sim-tracker-targets/1"
ROBOT_SPEC_FORMAT = "monoguide.sim-robot-spec/1"
FLANGE_NEST = "TCP"  # the tracker's name for the SMR on the flange tool
BASE_CALIBRATION_POSES = 24  # taught in the simulated robot program: wire pose numbers 101..124
CALIBRATION_STREAM = 0x43414C42  # "CALB": the calibration poses' own random stream (seeded with [sim] seed)


@dataclass(frozen=True)
class SimTarget:
    """A calibration target at ``T_cf_t`` with tracker-measurable points ``points_t`` (m, 3), mm."""

    name: str
    T_cf_t: np.ndarray
    points_t: np.ndarray


@dataclass(frozen=True, eq=False)
class SimMark:
    """A fixed reference mark of the cell (``[[reference_marks]]``): a dark disc of ``radius_mm`` on a light ground,
    centred at ``position_cf`` (3,) mm in the cell frame, in the plane of unit normal ``normal_cf`` (3,) (towards the
    cameras). Its SMR nest is a hidden-point nest: an SMR set in it has its centre at the mark's centre."""

    name: str
    position_cf: np.ndarray
    radius_mm: float
    normal_cf: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))


@dataclass(frozen=True)
class SimPartType:
    """One part type the simulated line supplies (the config's ``[[parts]]``): its holes, its reference, and the
    robot pose number of its first measuring pose (a part of this type arrives when that pose is requested)."""

    job: int
    points_w: np.ndarray
    hole_radius_mm: float
    T_cf_w0: np.ndarray
    point_names: tuple[str, ...]
    first_pose: int = 1
    outline_w: np.ndarray | None = None  # (m, 3) its outer edge in the part frame (hides the marks behind it)


@dataclass(frozen=True)
class SimCellSpec:
    """Everything that defines a simulated cell (built from the cell config by ``daemon.assembly``).

    ``T_cf_si`` are the calibrated measuring poses; the simulated robot's taught flange poses follow from
    them, the robot base ``T_cf_b`` and the true camera mounting ``T_f_c``. Deviation ranges are +- per
    axis of the part frame (translation mm; rotation deg about the centroid of ``points_w``).
    Repeatability is a per-axis standard deviation at the flange. ``marks`` are the cell's fixed reference marks;
    ``outline_w`` the current part's outer edge (a polygon in the part frame, None: not given), behind which the
    camera does not see a mark.
    """

    camera: CameraModel
    points_w: np.ndarray
    hole_radius_mm: float
    T_cf_w0: np.ndarray
    T_cf_b: np.ndarray
    T_cf_si: tuple[np.ndarray, ...]
    T_f_c: np.ndarray
    point_names: tuple[str, ...] = ()
    T_cf_tracker: np.ndarray = field(default_factory=lambda: np.eye(4))
    seed: int = 0
    deviation_translation_mm: tuple[float, float, float] = (50.0, 50.0, 5.0)
    deviation_rotation_deg: tuple[float, float, float] = (0.5, 0.5, 2.0)
    repeatability_mm: float = 0.05
    repeatability_deg: float = 0.01
    reported_repeatability_fraction: float = 1.0  # share of a stop's deviation the robot's reported pose sees
    tracker_noise_mm: float = 0.025
    exposure_us_nominal: float = 8000.0
    benchmarks_cf: dict[str, np.ndarray] = field(default_factory=dict)
    tool_smr_f: np.ndarray | None = None
    targets: tuple[SimTarget, ...] = ()
    T_w_g: np.ndarray | None = None  # taught grasp (gripper TCP) pose on the part; None: see SimCell.T_w_g
    focus_distance_mm: float | None = None  # the lens is sharp at this depth (camera z); None: no defocus
    aperture_mm: float = 0.0  # entrance pupil diameter: defocus grows with it away from the focus plane
    target_marks: TargetMarks | None = None  # the calibration targets' circular marks; None: the default target's
    part_types: tuple[SimPartType, ...] = ()  # every part type of the cell; the fields above hold the current one's
    marks: tuple[SimMark, ...] = ()  # the cell's fixed reference marks (on the fixture, beside the part)
    outline_w: np.ndarray | None = None  # (m, 3) the current part's outer edge in the part frame; None: not given


@dataclass
class SimScene:
    """What the person at the cell has put where during ``monoguide calibrate`` (set by the simulated operator,
    :mod:`monoguide.drivers.sim.calibration_scene`). A cell without a scene (``SimCell.scene`` None) is the
    production cell: every target's nests measurable where the spec puts them, the SMR on the flange.

    ``T_c_plate``: the circle plate held in front of the camera (its pose in the camera frame), or None;
    ``targets``: the calibration targets lying in the cell (measuring pose index -> ``T_cf_t``); ``part``: the
    part's pose ``T_cf_w`` (None: the part the robot's part supply presents); ``flange_smr``: the SMR tool is on
    the flange; ``beam_on``: the nest the tracker's beam is locked on."""

    plate: CirclePlate = field(default_factory=CirclePlate)
    T_c_plate: np.ndarray | None = None
    targets: dict[int, np.ndarray] = field(default_factory=dict)
    part: np.ndarray | None = None
    flange_smr: bool = False
    beam_on: str | None = None


class SimCell:
    """The truth of one simulated cell. Starts with the reference part in place and the robot at
    measuring pose 0 (with its repeatability noise drawn)."""

    def __init__(self, spec: SimCellSpec) -> None:
        self.spec = spec
        self.part_job = spec.part_types[0].job if spec.part_types else 1  # the part type in the cell
        self.rng = np.random.default_rng(spec.seed)
        self._T_cf_w = spec.T_cf_w0.copy()
        self._T_b_f_actual: dict[int, np.ndarray] = {}
        self.current_pose = 0
        self.scene: SimScene | None = None  # set by the simulated operator of `monoguide calibrate --sim`
        self.move_to_measuring_pose(0)

    @property
    def camera(self) -> CameraModel:
        return self.spec.camera

    @property
    def n_measuring_poses(self) -> int:
        return len(self.spec.T_cf_si)

    # --- the part -------------------------------------------------------------------------------

    @property
    def T_cf_w_true(self) -> np.ndarray:
        """Where the current part really lies, in the cell frame (4, 4)."""
        return self._T_cf_w.copy()

    def new_part(self, rng: np.random.Generator | None = None) -> np.ndarray:
        """Put a new part in the cell, deviated from the reference by a random draw within the configured
        ranges; returns its true pose ``T_cf_w``."""
        s = self.spec
        self.set_part_pose(deviated_part(rng if rng is not None else self.rng, s.T_cf_w0, s.points_w.mean(axis=0),
                                         s.deviation_translation_mm, s.deviation_rotation_deg))
        return self.T_cf_w_true

    def reference_part(self) -> np.ndarray:
        """Put the reference part (the one the grasp path was taught on) back in place."""
        self.set_part_pose(self.spec.T_cf_w0)
        return self.T_cf_w_true

    def set_part_pose(self, T_cf_w: np.ndarray) -> None:
        self._T_cf_w = np.array(T_cf_w, dtype=float)

    def set_part_type(self, job: int) -> None:
        """A part of type ``job`` is in the cell: its holes and reference become the spec's current ones."""
        if job == self.part_job:
            return
        part = self.part_type(job)
        self.spec = replace(self.spec, points_w=part.points_w, hole_radius_mm=part.hole_radius_mm,
                            T_cf_w0=part.T_cf_w0, point_names=part.point_names, T_w_g=None, outline_w=part.outline_w)
        self.part_job = job

    def part_type(self, job: int) -> SimPartType:
        for part in self.spec.part_types:
            if part.job == job:
                return part
        raise ValueError(f"part type {job} is not one of the cell's ({[p.job for p in self.spec.part_types]})")

    def points_cf_true(self) -> np.ndarray:
        """The featured hole centres of the current part in the cell frame, (n, 3)."""
        return transform_points(self._T_cf_w, self.spec.points_w)

    # --- the robot and the camera ---------------------------------------------------------------

    def T_b_f_taught(self, i: int) -> np.ndarray:
        """The taught flange pose of measuring pose ``i`` in the robot base frame."""
        s = self.spec
        return compose(invert(s.T_cf_b), s.T_cf_si[self._check_pose(i)], invert(s.T_f_c))

    def move_to_measuring_pose(self, i: int, rng: np.random.Generator | None = None) -> np.ndarray:
        """The robot goes to measuring pose ``i`` and stops a little off it (repeatability); returns the
        actual flange pose ``T_b_f``."""
        rng = rng if rng is not None else self.rng
        s = self.spec
        noise = make_T(
            rotvec_to_matrix(rng.normal(0.0, math.radians(s.repeatability_deg), 3)),
            rng.normal(0.0, s.repeatability_mm, 3),
        )
        self._T_b_f_actual[i] = compose(self.T_b_f_taught(i), noise)
        self.current_pose = i
        return self._T_b_f_actual[i].copy()

    def actual_flange_pose(self, i: int | None = None) -> np.ndarray:
        """``T_b_f`` of the last stop at measuring pose ``i`` (default: where the robot is now)."""
        i = self.current_pose if i is None else self._check_pose(i)
        if i not in self._T_b_f_actual:
            raise ValueError(f"the robot has not been at measuring pose {i} yet")
        return self._T_b_f_actual[i].copy()

    def actual_camera_pose(self, i: int | None = None) -> np.ndarray:
        """``T_cf_si`` as it really is at the last stop at measuring pose ``i`` (default: now)."""
        s = self.spec
        return compose(s.T_cf_b, self.actual_flange_pose(i), s.T_f_c)

    def T_c_w_true(self, i: int | None = None) -> np.ndarray:
        """The part in the camera frame at the last stop at measuring pose ``i``: what the camera sees."""
        return compose(invert(self.actual_camera_pose(i)), self._T_cf_w)

    def T_s1_w_true(self) -> np.ndarray:
        """The perfect answer of a measurement: the part in the calibrated SF1 (``T_cf_si[0]``)."""
        return compose(invert(self.spec.T_cf_si[0]), self._T_cf_w)

    def T_s1_w0(self) -> np.ndarray:
        """The reference part in the calibrated SF1."""
        return compose(invert(self.spec.T_cf_si[0]), self.spec.T_cf_w0)

    def set_actual_flange_pose(self, i: int, T_b_f: np.ndarray) -> None:
        """The robot stands at measuring pose ``i`` with flange pose ``T_b_f``, as a simulated controller in
        another process reports it (its truth file, :func:`monoguide.drivers.sim.robot_motion.read_truth`)."""
        self._T_b_f_actual[self._check_pose(i)] = np.array(T_b_f, dtype=float)
        self.current_pose = i

    def calibration_flange_poses(self, n: int = BASE_CALIBRATION_POSES) -> list[np.ndarray]:
        """The base-calibration poses ``T_b_f`` taught in the simulated robot program (wire pose numbers
        101..100+n): spread around the robot, tilted (seeded from the spec's seed, their own stream)."""
        return base_calibration_poses(n, np.random.default_rng([self.spec.seed, CALIBRATION_STREAM]))

    @property
    def target_marks(self) -> TargetMarks:
        """The circular marks of the calibration targets (each in its own frame)."""
        return self.spec.target_marks if self.spec.target_marks is not None else default_target_marks()

    # --- the grasp (what the written offset is for) ---------------------------------------------

    @property
    def T_w_g(self) -> np.ndarray:
        """The taught grasp pose on the part: given in the spec, else the gripper above the holes' centroid,
        its z axis pointing down into the part."""
        if self.spec.T_w_g is not None:
            return np.array(self.spec.T_w_g, dtype=float)
        return make_T(np.diag([1.0, -1.0, -1.0]), self.spec.points_w.mean(axis=0))

    def T_b_w_true(self) -> np.ndarray:
        """The current part in the robot base frame."""
        return compose(invert(self.spec.T_cf_b), self._T_cf_w)

    def T_b_w0(self) -> np.ndarray:
        """The reference part (the grasp path was taught on it) in the robot base frame."""
        return compose(invert(self.spec.T_cf_b), self.spec.T_cf_w0)

    def T_b_g0(self) -> np.ndarray:
        """The taught grasp pose in the robot base frame (on the reference part)."""
        return compose(self.T_b_w0(), self.T_w_g)

    def write_robot_spec(self, path: str | os.PathLike[str], part: int = 0,
                         part_types: tuple[int, ...] = ()) -> Path:
        """Write what a simulated robot controller needs (taught poses, repeatability, the reference and the
        current part ``part`` in its base frame) for its process; atomically, it re-reads on change.
        ``part_types``: the jobs of the parts its part supply presents, in turn (default: the current type)."""
        path = Path(path)
        s = self.spec
        types = [self._supplied_type(p) for p in s.part_types] or [self._supplied_type(None)]
        data = {
            "format": ROBOT_SPEC_FORMAT,
            "part": part,
            "seed": s.seed,
            "repeatability_mm": s.repeatability_mm,
            "repeatability_deg": s.repeatability_deg,
            "reported_repeatability_fraction": s.reported_repeatability_fraction,
            "T_b_f_taught": [self.T_b_f_taught(i).tolist() for i in range(self.n_measuring_poses)],
            "T_b_f_calibration": [T.tolist() for T in self.calibration_flange_poses()],
            "T_b_w0": self.T_b_w0().tolist(),
            "T_b_w": self.T_b_w_true().tolist(),
            "T_b_g0": self.T_b_g0().tolist(),
            "part_supply": {  # what the controller needs to present new parts (drivers/sim/part_supply.py)
                "T_cf_b": s.T_cf_b.tolist(), "T_cf_w0": s.T_cf_w0.tolist(),
                "centre_w": s.points_w.mean(axis=0).tolist(),
                "translation_mm": list(s.deviation_translation_mm), "rotation_deg": list(s.deviation_rotation_deg),
                "types": types, "sequence": list(part_types or (self.part_job,)),
            },
        }
        return write_atomic(path, json.dumps(data, indent=1))

    def _supplied_type(self, part: SimPartType | None) -> dict[str, object]:
        """What the part supply needs of one part type (None: the spec's current part)."""
        s = self.spec
        if part is None or part.job == self.part_job:
            job, T_cf_w0, points, T_w_g = self.part_job, s.T_cf_w0, s.points_w, self.T_w_g
            first = part.first_pose if part is not None else 1
        else:
            job, T_cf_w0, points, first = part.job, part.T_cf_w0, part.points_w, part.first_pose
            T_w_g = make_T(np.diag([1.0, -1.0, -1.0]), points.mean(axis=0))
        T_b_w0 = compose(invert(s.T_cf_b), T_cf_w0)
        return {"job": job, "first_pose": first, "T_cf_w0": T_cf_w0.tolist(), "centre_w": points.mean(axis=0).tolist(),
                "T_b_w0": T_b_w0.tolist(), "T_b_g0": compose(T_b_w0, T_w_g).tolist()}

    # --- SMRs for the laser tracker -------------------------------------------------------------

    def smr_positions(self) -> dict[str, np.ndarray]:
        """Every nest the tracker can measure, in the cell frame (mm): the benchmarks, the calibration
        targets' points (``T1.1``, ...), the featured holes of the current part (``P1``, ...), the reference
        marks (under each mark's name: its nest is a hidden-point nest, the SMR's centre at the mark's centre,
        ``SimMark.position_cf``) and the SMR on the flange tool (``TCP``) at the robot's actual pose. With a
        :class:`SimScene`, only the targets placed (where they lie) and the flange SMR only when mounted; the
        marks are fixed in the cell, always there."""
        s = self.spec
        out = {name: np.asarray(p, dtype=float).copy() for name, p in s.benchmarks_cf.items()}
        for i, target in enumerate(s.targets):
            T_cf_t = target.T_cf_t if self.scene is None else self.scene.targets.get(i)
            if T_cf_t is None:
                continue
            for k, p in enumerate(transform_points(T_cf_t, target.points_t)):
                out[f"{target.name}.{k + 1}"] = p
        names = s.point_names or tuple(f"P{k + 1}" for k in range(len(s.points_w)))
        out.update(zip(names, self.points_cf_true(), strict=True))
        for mark in s.marks:
            if mark.name in out or mark.name == FLANGE_NEST:
                raise ValueError(f"reference mark {mark.name!r}: the tracker has another nest of that name")
            out[mark.name] = np.asarray(mark.position_cf, dtype=float).reshape(3).copy()
        if s.tool_smr_f is not None and (self.scene is None or self.scene.flange_smr):
            T_cf_f = compose(s.T_cf_b, self.actual_flange_pose())
            out[FLANGE_NEST] = transform_points(T_cf_f, np.asarray(s.tool_smr_f, dtype=float).reshape(1, 3))[0]
        return out

    def tracker_targets(self) -> dict[str, np.ndarray]:
        """:meth:`smr_positions` in the tracker's own frame, as the tracker measures them (a reference mark's
        under its name: the centre of the SMR in its hidden-point nest, which is the mark's centre)."""
        T_tracker_cf = invert(self.spec.T_cf_tracker)
        return {k: transform_points(T_tracker_cf, p.reshape(1, 3))[0] for k, p in self.smr_positions().items()}

    def write_tracker_targets(self, path: str | os.PathLike[str], beam_on: str | None = None,
                              robot_truth: str | os.PathLike[str] | None = None) -> Path:
        """Write the tracker's truth for the simulated tracker process (atomically: it re-reads on change).

        With ``robot_truth`` (the truth file of the simulated robot controller) the flange SMR is not a fixed
        nest: the file names that truth file, the robot base in the tracker's frame and the SMR's offset on the
        flange, and the tracker computes the SMR where the robot stands at the moment it measures."""
        path = Path(path)
        targets = self.tracker_targets()
        flange = None
        if robot_truth is not None and FLANGE_NEST in targets:
            del targets[FLANGE_NEST]
            flange = {"nest": FLANGE_NEST, "truth": str(Path(robot_truth).resolve()),
                      "T_tracker_b": compose(invert(self.spec.T_cf_tracker), self.spec.T_cf_b).tolist(),
                      "smr_f": [float(v) for v in np.asarray(self.spec.tool_smr_f, dtype=float).reshape(3)]}
        if beam_on is None and self.scene is not None:
            beam_on = self.scene.beam_on
        beam_on = beam_on if beam_on is not None else next(iter(targets), None)
        data = {
            "format": TARGETS_FORMAT,
            "noise_mm": self.spec.tracker_noise_mm,
            "beam_on": beam_on,
            "nests": {k: [float(v) for v in p] for k, p in targets.items()},
            **({"flange": flange} if flange is not None else {}),
        }
        return write_atomic(path, json.dumps(data, indent=1))

    # --- private --------------------------------------------------------------------------------

    def _check_pose(self, i: int) -> int:
        if not 0 <= i < len(self.spec.T_cf_si):
            raise ValueError(f"measuring pose {i} does not exist (the cell has {len(self.spec.T_cf_si)})")
        return i


def deviated_part(rng: np.random.Generator, T_cf_w0: np.ndarray, centre_w: np.ndarray,
                  translation_mm: tuple[float, ...], rotation_deg: tuple[float, ...]) -> np.ndarray:
    """``T_cf_w`` of a part deviated from the reference ``T_cf_w0`` by a uniform draw within +-``translation_mm``
    and +-``rotation_deg`` (per axis of the part frame, rotation about ``centre_w``)."""
    t = rng.uniform(-1.0, 1.0, 3) * np.asarray(translation_mm, dtype=float)
    r = np.radians(rng.uniform(-1.0, 1.0, 3) * np.asarray(rotation_deg, dtype=float))
    return compose(T_cf_w0, part_deviation(r, t, centre_w))


def part_deviation(rotvec_rad: np.ndarray, translation_mm: np.ndarray, centre_w: np.ndarray) -> np.ndarray:
    """``T_w0_w`` of a part turned by ``rotvec_rad`` about ``centre_w`` and shifted by ``translation_mm``
    (all in the reference part's frame)."""
    R = rotvec_to_matrix(np.asarray(rotvec_rad, dtype=float))
    c = np.asarray(centre_w, dtype=float)
    return make_T(R, c - R @ c + np.asarray(translation_mm, dtype=float))
