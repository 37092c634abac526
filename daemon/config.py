"""The cell configuration: one TOML file, typed and validated on load (:func:`load_cell_config`).

Sections: ``[cell]``, ``[camera]`` (+ ``[camera.intrinsics]``), ``[part]``, ``[reference]``,
``[[measuring_poses]]``, and the optional ``[tracker]``, ``[sim]``, ``[layout]``, ``[robot]``, ``[plc]``
(``docs/plc-interface.md``), ``[cell_frame]``, ``[calibration_target]`` and ``[calibration]`` (the provenance
``monoguide calibrate`` writes, ``docs/calibration.md``). Matrices are 4x4 row-major lists, lengths in mm,
angles in degrees. Relative paths are relative to the config file. The keys are documented in ``docs/cell-config.md``.

Strict: a bad file raises a :class:`ConfigError` naming the key, the value and why; a required key that
is missing is :class:`ConfigMissingKey` (never a zero), an unknown key or section is
:class:`ConfigUnknownKey` / :class:`ConfigUnknownSection` with the closest known name.

A later issue adds its section in three steps: a frozen dataclass, a reader ``_name(t: ConfigTable)``
below, and an entry in :data:`OPTIONAL_SECTIONS` together with a ``CellConfig`` field of the same name
(``None`` when the file has no such section).
"""

from __future__ import annotations

import os
import tomllib
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np

from monoguide.daemon.config_reader import (
    MATRIX_TOL,
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
from monoguide.solver.errors import RecordError
from monoguide.solver.frames import compose
from monoguide.solver.planning import DeviationEnvelope, LayoutConstraints

__all__ = [
    "MATRIX_TOL",
    "OPTIONAL_SECTIONS",
    "REQUIRED_SECTIONS",
    "CellConfig",
    "ConfigError",
    "ConfigMissingKey",
    "ConfigUnknownKey",
    "ConfigUnknownSection",
    "default_sim_state_file",
    "load_cell_config",
]

CAMERA_BACKENDS = ("genicam", "sim")
TRACKER_BACKENDS = ("serial", "sim")
ROBOT_BACKENDS = ("ur", "kuka", "sim-ur", "sim-kuka")
ROBOT_DEFAULT_PORTS = {"ur": 30004, "kuka": 54600}  # RTDE (fixed); the EKI channel's <PORT>
INTRINSICS_KEYS = tuple(f.name for f in fields(CameraModel))  # width, height, fx, ..., p2: all required


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
# the wizard's steps (daemon/calibrate_rig.py STEPS), the keys of [calibration.steps]
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
    return config


def default_sim_state_file() -> Path:
    """Where ``monoguide sim-cell`` says where its devices listen, unless ``[sim] state_file`` says otherwise."""
    run_dir = os.environ.get("XDG_RUNTIME_DIR") or f"/tmp/monoguide-{os.getuid()}"
    return Path(run_dir) / "monoguide-sim-cell.json"


# --- sections ----------------------------------------------------------------------------------


def _cell(t: ConfigTable) -> str:
    name = t.text("name")
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
        pixel_format=t.text("pixel_format", "Mono8"),
        exposure_us=t.number("exposure_us", None, positive=True),
        gain_db=t.number("gain_db", None),
        region=region,
        grab_timeout_s=t.number("grab_timeout_s", 2.0, positive=True),
        T_f_c=t.matrix("T_f_c", None),
    )
    t.done()
    return out


def _intrinsics(t: ConfigTable) -> CameraModel:
    """Every coefficient is required: a camera calibrated without distortion says ``k1 = 0.0``."""
    values = {key: t.integer(key, minimum=1) if key in ("width", "height") else t.number(key)
              for key in INTRINSICS_KEYS}
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
    poses = []
    for i, t in enumerate(entries):
        name = t.text("name", f"S{i + 1}")
        points = t.ints("points", None, tuple(range(n_points)))
        if bad := [p for p in points if not 0 <= p < n_points]:
            raise ConfigError(f"{t.where}.points = {list(points)}: {bad} not among the {n_points} points_w")
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
    port = t.text("port", None)
    if backend == "serial" and not port:
        raise ConfigError(f"{t.where}.port: backend 'serial' needs the serial port (e.g. /dev/ttyUSB0)")
    baud = t.integer("baud", 115200, minimum=1)
    out = TrackerConfig(backend, port, baud, t.number("timeout_s", 2.0, positive=True))
    t.done()
    return out


def _sim(t: ConfigTable) -> SimConfig:
    dev = t.optional_table("deviation")
    bench = t.optional_table("benchmarks")
    benchmarks = {k: bench.vector(k, 3) for k in list(bench.raw)}  # named by the cell: every key is a nest
    targets = []
    for tt in t.tables("targets"):
        targets.append(CalibrationTarget(tt.text("name"), tt.matrix("T_cf_t"), tt.points("points_t")))
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
        exposure_us_nominal=t.number("exposure_us_nominal", 8000.0, positive=True),
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
    port = t.integer("port", ROBOT_DEFAULT_PORTS[make], minimum=1)
    if make == "ur" and port != ROBOT_DEFAULT_PORTS["ur"]:
        raise ConfigError(f"{t.where}.port = {port}: a UR controller serves RTDE on 30004 only (ur_rtde cannot "
                          f"use another port)")
    if port > 65535:
        raise ConfigError(f"{t.where}.port = {port}: not a TCP port (1..65535)")
    out = RobotConfig(
        backend=backend,
        host=t.text("host", "127.0.0.1"),
        port=port,
        connect_timeout_s=t.number("connect_timeout_s", 3.0, positive=True),
        move_timeout_s=t.number("move_timeout_s", 30.0, positive=True),
        ack_timeout_s=t.number("ack_timeout_s", 2.0, positive=True),
        stale_timeout_s=t.number("stale_timeout_s", 1.0, positive=True),
        rtde_frequency_hz=t.number("rtde_frequency_hz", 125.0, positive=True),
        pose_tolerance_mm=t.number("pose_tolerance_mm", 1.0, positive=True),
        pose_tolerance_deg=t.number("pose_tolerance_deg", 0.1, positive=True),
        sim_move_time_s=t.number("sim_move_time_s", 0.5, nonnegative=True),
    )
    if out.rtde_frequency_hz > 500.0:
        raise ConfigError(f"{t.where}.rtde_frequency_hz = {out.rtde_frequency_hz:g}: a UR controller sends at "
                          f"most 500 Hz")
    t.done()
    return out


def _plc(t: ConfigTable) -> PlcConfig:
    out = PlcConfig(
        host=t.text("host"),
        port=t.integer("port", 502, minimum=1),
        unit=t.integer("unit", 1, minimum=1),
        base=t.integer("base", 0, minimum=0),
        word_order=t.choice("word_order", PLC_WORD_ORDERS, "big"),
        heartbeat_timeout_s=t.number("heartbeat_timeout_s", 2.0, positive=True),
        timeout_s=t.number("timeout_s", 1.0, positive=True),
        ack_timeout_s=t.number("ack_timeout_s", 10.0, positive=True),
    )
    for key, value, maximum in (("port", out.port, 65535), ("unit", out.unit, 255),
                                ("base", out.base, 65536 - PLC_BLOCK_SIZE)):
        if value > maximum:
            raise ConfigError(f"{t.where}.{key} = {value}: above {maximum}")
    t.done()
    return out


def _service(t: ConfigTable) -> ServiceConfig:
    out = ServiceConfig(
        keep_images=t.boolean("keep_images", True),
        images_max_mb=t.number("images_max_mb", 2000.0, positive=True),
        images_max_age_days=t.number("images_max_age_days", 30.0, positive=True),
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
    if len(benchmarks) < 3:
        raise ConfigError(f"{t.where}.benchmarks: {len(benchmarks)} nests ({sorted(benchmarks)}); the cell frame "
                          f"needs at least 3")
    t.done()
    return CellFrameConfig(method, benchmarks)


def _calibration_target(t: ConfigTable) -> CalibrationTargetConfig:
    nests = t.points("nests_t")
    if len(nests) < 3:
        raise ConfigError(f"{t.where}.nests_t: {len(nests)} nests; the target's frame needs at least 3")
    cols, rows = t.integer("marks_cols", minimum=2), t.integer("marks_rows", minimum=2)
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
