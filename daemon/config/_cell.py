"""The cell configuration: one TOML file, typed and validated on load (:func:`load_cell_config`).

Sections: ``[cell]``, ``[camera]`` (+ ``[camera.intrinsics]``), ``[part]``, ``[reference]``,
``[[measuring_poses]]``, and the optional ``[tracker]``, ``[sim]``, ``[layout]``, ``[robot]``, ``[plc]``
(``docs/plc-interface.md``), ``[cell_frame]``, ``[calibration_target]`` and ``[calibration]`` (the provenance
``monoguide calibrate`` writes, ``docs/calibration.md``). Matrices are 4x4 row-major lists, lengths in mm,
angles in degrees. Relative paths are relative to the config file. The keys are documented in ``docs/cell-config.md``.

Strict: a bad file raises a :class:`ConfigError` naming the key, the value and why; a required key that
is missing is :class:`ConfigMissingKey` (never a zero), an unknown key or section is
:class:`ConfigUnknownKey` / :class:`ConfigUnknownSection` with the closest known name. Every duration and
count has a documented range (:data:`BOUNDS`); names are non-empty and unique; hosts are addresses or host
names; a cell that runs cycles (it has ``[robot]`` or ``[plc]``) gives the pose solver the redundancy it needs
(:data:`MIN_OBSERVATIONS` hole images of at least three holes not on one line). A command that needs an
optional section asks for it with :func:`require_sections`.

A later issue adds its section in three steps: a frozen dataclass, a reader ``_name(t: ConfigTable)``
below, and an entry in :data:`OPTIONAL_SECTIONS` together with a ``CellConfig`` field of the same name
(``None`` when the file has no such section).
"""

from __future__ import annotations

import os
import tomllib
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field, fields
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np

from monoguide.daemon.config._reader import (
    MATRIX_TOL,
    Bounds,
    ConfigMissingKey,
    ConfigTable,
    ConfigUnknownKey,
    ConfigUnknownSection,
)
from monoguide.drivers.errors import ConfigError
from monoguide.drivers.plc_registers import BLOCK_SIZE as PLC_BLOCK_SIZE
from monoguide.drivers.plc_registers import WORD_ORDERS as PLC_WORD_ORDERS
from monoguide.solver.calibration.target import TargetMarks, grid_marks
from monoguide.solver.camera import CameraModel
from monoguide.solver.consistency import MIN_OBSERVATIONS
from monoguide.solver.errors import RecordError
from monoguide.solver.frames import compose
from monoguide.solver.planning import DeviationEnvelope, LayoutConstraints

__all__ = [
    "BOUNDS",
    "MATRIX_TOL",
    "MAX_MEASURING_POSES",
    "MIN_OBSERVATIONS",
    "OPTIONAL_SECTIONS",
    "REQUIRED_SECTIONS",
    "CellConfig",
    "ConfigError",
    "ConfigMissingKey",
    "ConfigUnknownKey",
    "ConfigUnknownSection",
    "default_sim_state_file",
    "load_cell_config",
    "require_sections",
]

CAMERA_BACKENDS = ("genicam", "sim")
TRACKER_BACKENDS = ("serial", "sim")
ROBOT_BACKENDS = ("ur", "kuka", "sim-ur", "sim-kuka")
ROBOT_DEFAULT_PORTS = {"ur": 30004, "kuka": 54600}  # RTDE (fixed); the EKI channel's <PORT>
INTRINSICS_KEYS = tuple(f.name for f in fields(CameraModel))  # width, height, fx, ..., p2: all required

# The documented range (docs/cell-config.md) of every duration and count, "section.key" -> Bounds; the loader
# refuses a value outside it (NaN and infinities included), naming the key, the value and the range.
BOUNDS: dict[str, Bounds] = {
    "camera.grab_timeout_s": Bounds(0.05, 60.0, "s"),
    "camera.exposure_us": Bounds(1.0, 10_000_000.0, "us"),
    "camera.intrinsics.width": Bounds(1, 65535, "px"),
    "camera.intrinsics.height": Bounds(1, 65535, "px"),
    "tracker.baud": Bounds(300, 4_000_000),
    "tracker.timeout_s": Bounds(0.05, 600.0, "s"),
    "robot.port": Bounds(1, 65535),
    "robot.connect_timeout_s": Bounds(0.05, 60.0, "s"),
    "robot.move_timeout_s": Bounds(0.05, 600.0, "s"),
    # a written offset's acknowledgement is waited out on SIGTERM: well inside systemd's TimeoutStopSec=30s
    "robot.ack_timeout_s": Bounds(0.05, 10.0, "s"),
    "robot.stale_timeout_s": Bounds(0.05, 10.0, "s"),
    "robot.rtde_frequency_hz": Bounds(1.0, 500.0, "Hz"),  # a UR controller sends at most 500 Hz
    "robot.sim_move_time_s": Bounds(0.0, 60.0, "s"),
    "plc.port": Bounds(1, 65535),
    "plc.unit": Bounds(1, 255),
    "plc.base": Bounds(0, 65536 - PLC_BLOCK_SIZE),  # the block's 34 registers must fit
    "plc.heartbeat_timeout_s": Bounds(0.1, 60.0, "s"),  # the service reads the heartbeat every 20 ms
    "plc.timeout_s": Bounds(0.05, 60.0, "s"),
    "plc.ack_timeout_s": Bounds(0.05, 600.0, "s"),
    "service.images_max_mb": Bounds(1.0, 10_000_000.0, "MB"),
    "service.images_max_age_days": Bounds(0.01, 3650.0, "days"),
    "sim.exposure_us_nominal": Bounds(1.0, 10_000_000.0, "us"),
    "calibration_target.marks_cols": Bounds(2, 1000),
    "calibration_target.marks_rows": Bounds(2, 1000),
}
MAX_MEASURING_POSES = 100  # the robot programs number them 1..100; 101 and up are the base-calibration poses
COLLINEAR_MM = 1e-3  # holes within this of one line leave the rotation about it unsolved


@dataclass(frozen=True)
class CameraConfig:
    backend: str
    intrinsics: CameraModel
    cti: Path | None = None
    serial: str | None = None
    user_name: str | None = None
    pixel_format: str = "Mono8"
    exposure_us: float | None = None
    gain_db: float | None = None
    region: tuple[int, int, int, int] | None = None  # offset_x, offset_y, width, height (px)
    grab_timeout_s: float = 2.0
    T_f_c: np.ndarray | None = None  # calibrated mounting of the camera on the flange


@dataclass(frozen=True)
class PartConfig:
    points_w: np.ndarray  # (n, 3) featured hole centres, mm
    hole_radius_mm: float
    point_names: tuple[str, ...]
    grasp_point_w: np.ndarray | None = None  # (3,) where the robot grips, mm; None: the holes' centroid
    normals_w: np.ndarray | None = None  # (n, 3) surface normal at each hole; None: the part's z axis


@dataclass(frozen=True)
class ReferenceConfig:
    T_cf_w0: np.ndarray  # the initial part the grasp path was taught on, in the cell frame
    T_cf_b: np.ndarray | None = None  # robot base in the cell frame


@dataclass(frozen=True)
class MeasuringPose:
    name: str
    T_cf_si: np.ndarray  # calibrated camera pose i in the cell frame (Eq. 6)
    points: tuple[int, ...]  # featured points expected in this view
    T_b_f: np.ndarray | None = None  # taught flange pose, when known


@dataclass(frozen=True)
class TrackerConfig:
    backend: str
    port: str | None = None
    baud: int = 115200
    timeout_s: float = 2.0


@dataclass(frozen=True)
class RobotConfig:
    """``[robot]``: which controller, where, and how long to wait for it (docs/robot-interface.md)."""

    backend: str  # "ur" | "kuka" | "sim-ur" | "sim-kuka"
    host: str = "127.0.0.1"  # the controller; sim-*: where the simulated controller listens
    port: int = 30004
    connect_timeout_s: float = 3.0
    move_timeout_s: float = 30.0  # request measuring pose -> in position
    ack_timeout_s: float = 2.0  # offset written -> acknowledged
    stale_timeout_s: float = 1.0  # no new state from the controller for this long: it has stalled
    rtde_frequency_hz: float = 125.0  # UR: the state recipe's frequency
    pose_tolerance_mm: float = 1.0  # in position, yet this far from the taught flange pose: refused
    pose_tolerance_deg: float = 0.1
    sim_move_time_s: float = 0.5  # sim-*: seconds per move to a measuring pose

    @property
    def make(self) -> str:
        """``"ur"`` or ``"kuka"``: the protocol, whether the controller is real or simulated."""
        return self.backend.removeprefix("sim-")

    @property
    def simulated(self) -> bool:
        return self.backend.startswith("sim-")


@dataclass(frozen=True)
class PlcConfig:
    """``[plc]``: the line's PLC, a Modbus TCP server (docs/plc-interface.md)."""

    host: str
    port: int = 502
    unit: int = 1  # Modbus unit (device) id
    base: int = 0  # holding register of the block's register 0
    word_order: str = "big"  # float32: "big" high word first, "little" low word first
    heartbeat_timeout_s: float = 2.0  # the PLC heartbeat must change at least this often
    timeout_s: float = 1.0  # connect and every request
    ack_timeout_s: float = 10.0  # DONE -> RESULT_ACK with TRIGGER low; longer: FAULT, PLC_ACK_TIMEOUT


@dataclass(frozen=True)
class ServiceConfig:
    """``[service]``: what ``monoguide run`` keeps of each cycle (docs/service.md)."""

    keep_images: bool = True  # write each cycle's camera images under <state dir>/images/cycle-<n>/
    images_max_mb: float = 2000.0  # the oldest cycles' images are deleted beyond this total size
    images_max_age_days: float = 30.0  # ... and beyond this age (the journal rows are kept)


@dataclass(frozen=True)
class ChecksConfig:
    """``[checks]``: what a cycle's result must pass before its offset goes to the robot (docs/cycle.md).
    ``None`` envelope keys: from ``[layout]`` (its per-axis envelope, the totals their norms), else the
    measurement record's default envelope (50 mm, 5 deg)."""

    max_rms_px: float = 1.0  # reprojection RMS above this: RESIDUAL_TOO_LARGE
    max_sigma_mm: float = 0.5  # predicted sigma of the grasp point above this: UNCERTAINTY_TOO_LARGE
    max_sigma_deg: float = 0.1  # predicted sigma of the rotation above this: UNCERTAINTY_TOO_LARGE
    false_alarm_rate: float = 1e-3  # the consistency test's (INCONSISTENT_MEASUREMENT)
    envelope_mm: float | None = None  # the grasp point's shift in total, mm
    envelope_deg: float | None = None  # the rotation angle, deg
    envelope_axis_mm: tuple[float, float, float] | None = None  # per axis of the reference part frame
    envelope_axis_deg: tuple[float, float, float] | None = None


@dataclass(frozen=True)
class SimConfig:
    seed: int = 0
    state_file: Path | None = None
    T_f_c: np.ndarray = field(default_factory=lambda: np.eye(4))  # true camera mounting
    T_cf_tracker: np.ndarray = field(default_factory=lambda: np.eye(4))
    deviation_translation_mm: tuple[float, float, float] = (50.0, 50.0, 5.0)
    deviation_rotation_deg: tuple[float, float, float] = (0.5, 0.5, 2.0)
    repeatability_mm: float = 0.05
    repeatability_deg: float = 0.01
    reported_repeatability_fraction: float = 1.0  # share of a stop's deviation the robot's report sees
    truth_config: Path | None = None  # the simulated devices' cell (monoguide simulate --calibration)
    tracker_noise_mm: float = 0.025
    exposure_us_nominal: float = 8000.0
    benchmarks: dict[str, np.ndarray] = field(default_factory=dict)  # SMR nests in the cell frame
    tool_smr_f: np.ndarray | None = None  # SMR on the flange tool, in the flange frame
    targets: tuple[CalibrationTarget, ...] = ()
    focus_distance_mm: float | None = None  # where the simulated lens is sharp; None: no defocus
    aperture_mm: float = 0.0  # the simulated lens's entrance pupil (focal length / f-number); 0: no defocus


@dataclass(frozen=True)
class LayoutConfig:
    """``[layout]``: what ``monoguide plan --layout`` plans the measuring poses for (docs/planning.md)."""

    constraints: LayoutConstraints = field(default_factory=LayoutConstraints)
    envelope: DeviationEnvelope = field(default_factory=DeviationEnvelope)
    sigma_px: float = 0.1
    repeatability_mm: float = 0.05
    repeatability_deg: float = 0.01
    reach_radius_mm: float | None = None  # flange within this distance of the robot base ([reference] T_cf_b)


@dataclass(frozen=True)
class CalibrationTarget:
    name: str
    T_cf_t: np.ndarray
    points_t: np.ndarray  # (m, 3) tracker-measurable points (nests in its featured holes), target frame


CELL_FRAME_METHODS = ("best-fit", "3-2-1")
# the wizard's steps (daemon/calibrate/_rig.py STEPS), the keys of [calibration.steps]
CALIBRATION_STEPS = ("intrinsics", "cell", "base", "part", "sfi", "verify", "accuracy")


@dataclass(frozen=True)
class CellFrameConfig:
    """``[cell_frame]``: the benchmark SMR nests that define the cell frame CF (docs/calibration.md)."""

    method: str  # "best-fit" (all benchmarks) or "3-2-1" (origin at the first, x to the second, xy through the third)
    benchmarks: dict[str, np.ndarray]  # nest name -> nominal coordinates in CF, mm (file order kept)


@dataclass(frozen=True)
class CalibrationTargetConfig:
    """``[calibration_target]``: the target with circular marks the measuring poses are calibrated with."""

    nests_t: np.ndarray  # (m, 3) its SMR nests in its own frame TF, mm (tracker names T<i>.<k>, k 1-based)
    marks: TargetMarks  # marks_cols x marks_rows marks at marks_pitch_mm from marks_origin_t


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


def load_cell_config(path: str | os.PathLike[str]) -> CellConfig:
    """Read and validate a cell file; raises :class:`ConfigError` naming the key, the value and why."""
    path = Path(path)
    try:
        raw = tomllib.loads(path.read_text())
    except FileNotFoundError as exc:
        raise ConfigError(f"{path}: no such config file") from exc
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: cannot read: {exc}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from exc
    root = ConfigTable(raw, path)
    root.reject_unknown((*REQUIRED_SECTIONS, *OPTIONAL_SECTIONS))  # first: a misspelt section is not "missing"
    name = _cell(root.table("cell"))
    camera = _camera(root.table("camera"))
    part = _part(root.table("part"))
    reference = _reference(root.table("reference"))
    poses = _measuring_poses(root.tables("measuring_poses", required=True), reference, camera, len(part.points_w))
    optional = {key: read(root.table(key)) if root.has(key) else None for key, read in OPTIONAL_SECTIONS.items()}
    config = CellConfig(path, name, camera, part, reference, poses, **optional)
    _check_backends(config)
    if config.robot is not None or config.plc is not None:  # a cell that runs cycles
        _check_redundancy(config)
    return config


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


def default_sim_state_file() -> Path:
    """Where ``monoguide sim-cell`` says where its devices listen, unless ``[sim] state_file`` says otherwise."""
    run_dir = os.environ.get("XDG_RUNTIME_DIR") or f"/tmp/monoguide-{os.getuid()}"
    return Path(run_dir) / "monoguide-sim-cell.json"


# --- sections ----------------------------------------------------------------------------------


def _cell(t: ConfigTable) -> str:
    name = t.text("name", nonempty=True)
    t.done()
    return name


def _camera(t: ConfigTable) -> CameraConfig:
    backend = t.choice("backend", CAMERA_BACKENDS)
    model = _intrinsics(t.table("intrinsics"))
    in_genicam_wheel = str(t.raw.get("cti", "")).startswith("genicam:")
    cti = t.path("cti", None)
    if in_genicam_wheel:  # "genicam:NAME": a producer the genicam wheel ships, wherever that is installed
        from importlib.util import find_spec

        package = find_spec("genicam")
        if package is None or package.origin is None:
            raise ConfigError(f"{t.where}.cti: the genicam package is not installed")
        cti = Path(package.origin).parent / cti.name.removeprefix("genicam:")
    if backend == "genicam" and cti is None:
        raise ConfigError(f"{t.where}.cti: backend 'genicam' needs the GenTL producer (.cti) path")
    region = t.ints("region", 4, None)
    if region is not None and (region[2] <= 0 or region[3] <= 0 or min(region[:2]) < 0):
        raise ConfigError(f"{t.where}.region = {list(region)}: needs offset_x, offset_y >= 0, width, height > 0")
    out = CameraConfig(
        backend=backend,
        intrinsics=model,
        cti=cti,
        serial=t.text("serial", None),
        user_name=t.text("user_name", None),
        pixel_format=t.text("pixel_format", "Mono8", nonempty=True),
        exposure_us=_number(t, "exposure_us", None),
        gain_db=t.number("gain_db", None),
        region=region,
        grab_timeout_s=_number(t, "grab_timeout_s", 2.0),
        T_f_c=t.matrix("T_f_c", None),
    )
    t.done()
    return out


def _intrinsics(t: ConfigTable) -> CameraModel:
    """Every coefficient is required: a camera calibrated without distortion says ``k1 = 0.0``."""
    values = {key: _integer(t, key) if key in ("width", "height") else t.number(key) for key in INTRINSICS_KEYS}
    t.done()
    try:
        return CameraModel.from_dict(values, where=t.where)
    except RecordError as exc:
        raise ConfigError(exc.message) from exc


def _part(t: ConfigTable) -> PartConfig:
    points = t.points("points_w")
    names = t.texts("point_names", tuple(f"P{i + 1}" for i in range(len(points))))
    if len(names) != len(points):
        raise ConfigError(f"{t.where}.point_names: {len(names)} names for {len(points)} points_w")
    _unique_names(names, f"{t.where}.point_names")
    normals = t.points("normals_w") if t.has("normals_w") else None
    if normals is not None and (len(normals) != len(points) or np.any(np.linalg.norm(normals, axis=1) < 1e-9)):
        raise ConfigError(f"{t.where}.normals_w: expected one non-zero normal per point of points_w ({len(points)})")
    out = PartConfig(points, t.number("hole_radius_mm", positive=True), names, t.vector("grasp_point_w", 3, None),
                     normals)
    t.done()
    return out


def _reference(t: ConfigTable) -> ReferenceConfig:
    out = ReferenceConfig(t.matrix("T_cf_w0"), t.matrix("T_cf_b", None))
    t.done()
    return out


def _measuring_poses(entries: list[ConfigTable], ref: ReferenceConfig, cam: CameraConfig,
                     n_points: int) -> tuple[MeasuringPose, ...]:
    if len(entries) > MAX_MEASURING_POSES:
        raise ConfigError(f"{entries[0].file}: [[measuring_poses]]: {len(entries)} poses: must be 1 to "
                          f"{MAX_MEASURING_POSES} (the robot programs' pose numbers 101 and up are base-calibration "
                          "poses)")
    poses: list[MeasuringPose] = []
    for i, t in enumerate(entries):
        name = t.text("name", f"S{i + 1}", nonempty=True)
        if (first := next((j for j, p in enumerate(poses) if p.name == name), None)) is not None:
            raise ConfigError(f"{t.where}.name = {name!r}: already the name of [[measuring_poses]] #{first + 1}; "
                              "each pose's images, taught pose and calibration are filed under its own name")
        points = t.ints("points", None, tuple(range(n_points)))
        if not points:
            raise ConfigError(f"{t.where}.points = []: a measuring pose sees at least one featured hole")
        if bad := [p for p in points if not 0 <= p < n_points]:
            raise ConfigError(f"{t.where}.points = {list(points)}: {bad} not among the {n_points} points_w")
        if twice := sorted({p for p in points if points.count(p) > 1}):
            raise ConfigError(f"{t.where}.points = {list(points)}: {twice} listed twice (one image of a hole per view)")
        T_cf_si, T_b_f = t.matrix("T_cf_si", None), t.matrix("T_b_f", None)
        if T_cf_si is None:
            if T_b_f is None or ref.T_cf_b is None or cam.T_f_c is None:
                raise ConfigError(f"{t.where}: give T_cf_si, or T_b_f with [reference] T_cf_b and [camera] T_f_c")
            T_cf_si = compose(ref.T_cf_b, T_b_f, cam.T_f_c)
        t.done()
        poses.append(MeasuringPose(name, T_cf_si, points, T_b_f))
    return tuple(poses)


def _tracker(t: ConfigTable) -> TrackerConfig:
    backend = t.choice("backend", TRACKER_BACKENDS)
    port = t.text("port", None, nonempty=True)
    if backend == "serial" and not port:
        raise ConfigError(f"{t.where}.port: backend 'serial' needs the serial port (e.g. /dev/ttyUSB0)")
    baud = _integer(t, "baud", 115200)
    out = TrackerConfig(backend, port, baud, _number(t, "timeout_s", 2.0))
    t.done()
    return out


def _sim(t: ConfigTable) -> SimConfig:
    dev = t.optional_table("deviation")
    bench = t.optional_table("benchmarks")
    benchmarks = {k: bench.vector(k, 3) for k in list(bench.raw)}  # named by the cell: every key is a nest
    _nest_names(benchmarks, bench.where)
    targets: list[CalibrationTarget] = []
    for tt in t.tables("targets"):
        name = tt.text("name", nonempty=True)
        if name in [target.name for target in targets]:
            raise ConfigError(f"{tt.where}.name = {name!r}: another [[sim.targets]] has this name already")
        targets.append(CalibrationTarget(name, tt.matrix("T_cf_t"), tt.points("points_t")))
        tt.done()
    out = SimConfig(
        seed=t.integer("seed", 0, minimum=0),
        state_file=t.path("state_file", None),
        T_f_c=t.matrix("T_f_c", np.eye(4)),
        T_cf_tracker=t.matrix("T_cf_tracker", np.eye(4)),
        deviation_translation_mm=tuple(dev.vector("translation_mm", 3, (50.0, 50.0, 5.0))),
        deviation_rotation_deg=tuple(dev.vector("rotation_deg", 3, (0.5, 0.5, 2.0))),
        repeatability_mm=t.number("repeatability_mm", 0.05, nonnegative=True),
        repeatability_deg=t.number("repeatability_deg", 0.01, nonnegative=True),
        reported_repeatability_fraction=t.number("reported_repeatability_fraction", 1.0, nonnegative=True),
        truth_config=t.path("truth_config", None),
        tracker_noise_mm=t.number("tracker_noise_mm", 0.025, nonnegative=True),
        exposure_us_nominal=_number(t, "exposure_us_nominal", 8000.0),
        benchmarks=benchmarks,
        tool_smr_f=t.vector("tool_smr_f", 3, None),
        targets=tuple(targets),
        focus_distance_mm=t.number("focus_distance_mm", None, positive=True),
        aperture_mm=t.number("aperture_mm", 0.0, nonnegative=True),
    )
    if out.reported_repeatability_fraction > 1.0:
        raise ConfigError(f"{t.where}.reported_repeatability_fraction = {out.reported_repeatability_fraction}: "
                          "expected 0 (the report sees none of a stop's deviation) .. 1 (all of it)")
    if out.aperture_mm > 0 and out.focus_distance_mm is None:
        raise ConfigError(f"{t.where}.aperture_mm = {out.aperture_mm}: a defocused lens needs focus_distance_mm")
    dev.done()
    t.done()
    return out


def _layout(t: ConfigTable) -> LayoutConfig:
    default, envelope = LayoutConstraints(), DeviationEnvelope()
    standoff = tuple(t.vector("standoff_mm", 2, default.standoff_mm))
    depth = tuple(t.vector("depth_of_field_mm", 2, default.depth_of_field_mm))
    for key, (low, high) in (("standoff_mm", standoff), ("depth_of_field_mm", depth)):
        if not 0 < low <= high:
            raise ConfigError(f"{t.where}.{key} = {[float(low), float(high)]}: expected [min, max] with "
                              "0 < min <= max (mm)")
    angle = t.number("max_view_angle_deg", default.max_view_angle_deg, nonnegative=True)
    if angle >= 90.0:
        raise ConfigError(f"{t.where}.max_view_angle_deg = {angle}: must be below 90")
    translation = tuple(float(v) for v in t.vector("envelope_translation_mm", 3, envelope.translation_mm))
    rotation = tuple(float(v) for v in t.vector("envelope_rotation_deg", 3, envelope.rotation_deg))
    if min(translation) < 0 or min(rotation) < 0 or max(rotation) >= 45.0:
        raise ConfigError(f"{t.where}: envelope_translation_mm = {list(translation)}, envelope_rotation_deg = "
                          f"{list(rotation)}: expected +- ranges >= 0 (rotations below 45)")
    centre = t.vector("envelope_centre_w", 3, None)
    out = LayoutConfig(
        constraints=LayoutConstraints(
            standoff_mm=(float(standoff[0]), float(standoff[1])),
            max_view_angle_deg=angle,
            margin_px=t.number("margin_px", default.margin_px, nonnegative=True),
            depth_of_field_mm=(float(depth[0]), float(depth[1])),
            max_view_angle_envelope_deg=t.number("max_view_angle_envelope_deg", None, positive=True),
        ),
        envelope=DeviationEnvelope(translation, rotation, None if centre is None else tuple(float(v) for v in centre)),
        sigma_px=t.number("sigma_px", 0.1, positive=True),
        repeatability_mm=t.number("repeatability_mm", 0.05, nonnegative=True),
        repeatability_deg=t.number("repeatability_deg", 0.01, nonnegative=True),
        reach_radius_mm=t.number("reach_radius_mm", None, positive=True),
    )
    t.done()
    return out


def _robot(t: ConfigTable) -> RobotConfig:
    backend = t.choice("backend", ROBOT_BACKENDS)
    make = backend.removeprefix("sim-")
    port = _integer(t, "port", ROBOT_DEFAULT_PORTS[make])
    if make == "ur" and port != ROBOT_DEFAULT_PORTS["ur"]:
        raise ConfigError(f"{t.where}.port = {port}: a UR controller serves RTDE on 30004 only (ur_rtde cannot "
                          f"use another port)")
    out = RobotConfig(
        backend=backend,
        host=t.host("host", "127.0.0.1"),
        port=port,
        connect_timeout_s=_number(t, "connect_timeout_s", 3.0),
        move_timeout_s=_number(t, "move_timeout_s", 30.0),
        ack_timeout_s=_number(t, "ack_timeout_s", 2.0),
        stale_timeout_s=_number(t, "stale_timeout_s", 1.0),
        rtde_frequency_hz=_number(t, "rtde_frequency_hz", 125.0),
        pose_tolerance_mm=t.number("pose_tolerance_mm", 1.0, positive=True),
        pose_tolerance_deg=t.number("pose_tolerance_deg", 0.1, positive=True),
        sim_move_time_s=_number(t, "sim_move_time_s", 0.5),
    )
    if make == "ur" and out.stale_timeout_s < 2.0 / out.rtde_frequency_hz:
        raise ConfigError(f"{t.where}.stale_timeout_s = {out.stale_timeout_s:g}: must be at least two periods of "
                          f"rtde_frequency_hz = {out.rtde_frequency_hz:g} Hz ({2.0 / out.rtde_frequency_hz:g} s), or "
                          f"every pause between two states counts as a stalled controller")
    t.done()
    return out


def _plc(t: ConfigTable) -> PlcConfig:
    out = PlcConfig(
        host=t.host("host"),
        port=_integer(t, "port", 502),
        unit=_integer(t, "unit", 1),
        base=_integer(t, "base", 0),
        word_order=t.choice("word_order", PLC_WORD_ORDERS, "big"),
        heartbeat_timeout_s=_number(t, "heartbeat_timeout_s", 2.0),
        timeout_s=_number(t, "timeout_s", 1.0),
        ack_timeout_s=_number(t, "ack_timeout_s", 10.0),
    )
    t.done()
    return out


def _service(t: ConfigTable) -> ServiceConfig:
    out = ServiceConfig(
        keep_images=t.boolean("keep_images", True),
        images_max_mb=_number(t, "images_max_mb", 2000.0),
        images_max_age_days=_number(t, "images_max_age_days", 30.0),
    )
    t.done()
    return out


def _checks(t: ConfigTable) -> ChecksConfig:
    axis_mm, axis_deg = t.vector("envelope_axis_mm", 3, None), t.vector("envelope_axis_deg", 3, None)
    for key, value in (("envelope_axis_mm", axis_mm), ("envelope_axis_deg", axis_deg)):
        if value is not None and min(value) <= 0:
            raise ConfigError(f"{t.where}.{key} = {[float(v) for v in value]}: expected 3 limits > 0")
    rate = t.number("false_alarm_rate", 1e-3, positive=True)
    if rate >= 1.0:
        raise ConfigError(f"{t.where}.false_alarm_rate = {rate}: must lie between 0 and 1")
    out = ChecksConfig(
        max_rms_px=t.number("max_rms_px", 1.0, positive=True),
        max_sigma_mm=t.number("max_sigma_mm", 0.5, positive=True),
        max_sigma_deg=t.number("max_sigma_deg", 0.1, positive=True),
        false_alarm_rate=rate,
        envelope_mm=t.number("envelope_mm", None, positive=True),
        envelope_deg=t.number("envelope_deg", None, positive=True),
        envelope_axis_mm=None if axis_mm is None else tuple(float(v) for v in axis_mm),
        envelope_axis_deg=None if axis_deg is None else tuple(float(v) for v in axis_deg),
    )
    t.done()
    return out


def _cell_frame(t: ConfigTable) -> CellFrameConfig:
    method = t.choice("method", CELL_FRAME_METHODS, "best-fit")
    bench = t.table("benchmarks")
    benchmarks = {k: bench.vector(k, 3) for k in list(bench.raw)}  # named by the cell: every key is a nest
    bench.done()
    _nest_names(benchmarks, bench.where)
    if len(benchmarks) < 3:
        raise ConfigError(f"{t.where}.benchmarks: {len(benchmarks)} nests ({sorted(benchmarks)}); the cell frame "
                          f"needs at least 3")
    t.done()
    return CellFrameConfig(method, benchmarks)


def _calibration_target(t: ConfigTable) -> CalibrationTargetConfig:
    nests = t.points("nests_t")
    if len(nests) < 3:
        raise ConfigError(f"{t.where}.nests_t: {len(nests)} nests; the target's frame needs at least 3")
    cols, rows = _integer(t, "marks_cols"), _integer(t, "marks_rows")
    pitch = t.number("marks_pitch_mm", positive=True)
    radius = t.number("marks_radius_mm", positive=True)
    if radius >= pitch / 2:
        raise ConfigError(f"{t.where}.marks_radius_mm = {radius:g}: marks of this radius touch at a pitch of "
                          f"{pitch:g} mm (must be below {pitch / 2:g})")
    origin = t.vector("marks_origin_t", 3)
    t.done()
    grid = grid_marks(cols, rows, pitch, radius, (float(origin[0]), float(origin[1])))
    centres = grid.centers_t.copy()
    centres[:, 2] = origin[2]
    return CalibrationTargetConfig(nests, TargetMarks(centres, radius))


def _calibration(t: ConfigTable) -> dict[str, Any]:
    """Provenance, read loosely but typed: the wizard's keys are known (a misspelt one is refused), the devices
    and the per-step summaries take any names (steps: one of CALIBRATION_STEPS)."""
    out: dict[str, Any] = {}
    if isinstance(t.raw.get("date"), datetime):  # an unquoted TOML date-time is as good as its text
        t.raw["date"] = t.raw["date"].isoformat()
    date = t.text("date", None)
    if date is not None:
        try:
            datetime.fromisoformat(date)
        except ValueError as exc:
            raise ConfigError(f"{t.where}.date = {date!r}: expected an ISO 8601 date-time") from exc
        out["date"] = date
    for key in ("session", "wizard_version", "previous"):
        if (value := t.text(key, None)) is not None:
            out[key] = value
    if (sim := t.boolean("sim", None)) is not None:
        out["sim"] = sim
    devices = t.optional_table("devices")
    out["devices"] = {k: devices.text(k) for k in list(devices.raw)}  # named by the cell: camera, tracker, ...
    devices.done()
    steps = t.optional_table("steps")
    out["steps"] = {}
    for name in [k for k in CALIBRATION_STEPS if steps.has(k)]:
        step = steps.table(name)
        out["steps"][name] = {k: _provenance_value(step, k) for k in list(step.raw)}
        step.done()
    steps.done()
    t.done()
    return out


def _provenance_value(t: ConfigTable, key: str) -> Any:
    value = t.raw.get(key)
    if isinstance(value, str | bool):
        return t.boolean(key) if isinstance(value, bool) else t.text(key)
    if isinstance(value, list):
        return [float(v) for v in t.vector(key, len(value))]
    if isinstance(value, int):
        return t.integer(key)
    if isinstance(value, float):
        return t.number(key)
    raise ConfigError(f"{t.where}.{key} = {value!r}: expected a number, string, true/false or a list of numbers")


def _number(t: ConfigTable, key: str, *default: Any) -> Any:
    """A number within its documented range, :data:`BOUNDS` ``[section.key]``."""
    return t.number(key, *default, bounds=BOUNDS[f"{t.name}.{key}"])


def _integer(t: ConfigTable, key: str, *default: Any) -> Any:
    """An integer within its documented range, :data:`BOUNDS` ``[section.key]``."""
    return t.integer(key, *default, bounds=BOUNDS[f"{t.name}.{key}"])


def _unique_names(names: tuple[str, ...], where: str) -> None:
    for i, name in enumerate(names):
        if not name.strip():
            raise ConfigError(f"{where} = {list(names)}: name #{i + 1} is empty")
        if name in names[:i]:
            raise ConfigError(f"{where} = {list(names)}: {name!r} names two points")


def _nest_names(nests: dict[str, np.ndarray], where: str) -> None:
    if any(not name.strip() for name in nests):
        raise ConfigError(f"{where}: a nest with an empty name ({sorted(nests)})")


def _check_redundancy(config: CellConfig) -> None:
    """The measuring poses together give the pose solver what it needs: at least :data:`MIN_OBSERVATIONS` hole
    images (two equations each for the pose's six unknowns, and a degree of freedom left for the chi-square
    consistency check, solver/consistency.py) of at least three holes not on one line (otherwise the rotation
    about that line is not observed). Without it every cycle would fail at run time."""
    poses, names = config.measuring_poses, config.part.point_names
    seen = [(pose.name, j) for pose in poses for j in pose.points]
    holes = sorted({j for _, j in seen})
    where = f"{config.path}: [[measuring_poses]] {', '.join(p.name for p in poses)}"
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


def _check_backends(config: CellConfig) -> None:
    """Simulated back-ends need the ``[sim]`` section they are built from."""
    if config.camera.backend == "sim" and config.sim is None:
        raise ConfigError(f"{config.path}: [camera].backend = 'sim' needs a [sim] section")
    if config.tracker is not None and config.tracker.backend == "sim" and config.sim is None:
        raise ConfigError(f"{config.path}: [tracker].backend = 'sim' needs a [sim] section")
    if config.robot is not None and config.robot.simulated and config.sim is None:
        raise ConfigError(f"{config.path}: [robot].backend = {config.robot.backend!r} needs a [sim] section")


REQUIRED_SECTIONS = ("cell", "camera", "part", "reference", "measuring_poses")

# name -> reader of the optional sections; each has a CellConfig field of the same name. Add yours here.
OPTIONAL_SECTIONS: dict[str, Callable[[ConfigTable], Any]] = {
    "tracker": _tracker,
    "sim": _sim,
    "layout": _layout,
    "robot": _robot,
    "plc": _plc,
    "service": _service,
    "checks": _checks,
    "cell_frame": _cell_frame,
    "calibration_target": _calibration_target,
    "calibration": _calibration,
}
