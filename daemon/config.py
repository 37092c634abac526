"""The cell configuration: one TOML file, typed and validated on load (:func:`load_cell_config`).

Sections: ``[cell]``, ``[camera]`` (+ ``[camera.intrinsics]``), ``[part]``, ``[reference]``,
``[[measuring_poses]]``, ``[tracker]``, ``[sim]``. A bad file raises :class:`ConfigError` naming the key,
the value and why. Matrices are 4x4 row-major lists, lengths in mm, angles in degrees. Relative paths
are relative to the config file. Later issues add their sections (robot, PLC) here; a section this
schema does not know yet is kept raw in :attr:`CellConfig.extra_sections` and logged.
"""

from __future__ import annotations

import logging
import math
import os
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from monoguide.drivers.errors import ConfigError
from monoguide.solver.camera import CameraModel
from monoguide.solver.errors import RecordError
from monoguide.solver.frames import compose, orthonormalize

log = logging.getLogger(__name__)

MATRIX_TOL = 2e-3  # printed calibration matrices are rounded to 4 decimals; re-orthonormalised on load
CAMERA_BACKENDS = ("genicam", "sim")
TRACKER_BACKENDS = ("serial", "sim")


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
class SimConfig:
    seed: int = 0
    state_file: Path | None = None
    T_f_c: np.ndarray = field(default_factory=lambda: np.eye(4))  # true camera mounting
    T_cf_tracker: np.ndarray = field(default_factory=lambda: np.eye(4))
    deviation_translation_mm: tuple[float, float, float] = (50.0, 50.0, 5.0)
    deviation_rotation_deg: tuple[float, float, float] = (0.5, 0.5, 2.0)
    repeatability_mm: float = 0.05
    repeatability_deg: float = 0.01
    tracker_noise_mm: float = 0.025
    exposure_us_nominal: float = 8000.0
    benchmarks: dict[str, np.ndarray] = field(default_factory=dict)  # SMR nests in the cell frame
    tool_smr_f: np.ndarray | None = None  # SMR on the flange tool, in the flange frame
    targets: tuple[CalibrationTarget, ...] = ()


@dataclass(frozen=True)
class CalibrationTarget:
    name: str
    T_cf_t: np.ndarray
    points_t: np.ndarray  # (m, 3) tracker-measurable points (nests in its featured holes), target frame


@dataclass(frozen=True)
class CellConfig:
    path: Path
    name: str
    camera: CameraConfig
    part: PartConfig
    reference: ReferenceConfig
    measuring_poses: tuple[MeasuringPose, ...]
    tracker: TrackerConfig | None = None
    sim: SimConfig | None = None
    extra_sections: dict[str, Any] = field(default_factory=dict)


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
    root = _Table(raw, str(path), path.parent)
    known = ("cell", "camera", "part", "reference", "measuring_poses", "tracker", "sim")
    extra = {k: v for k, v in raw.items() if k not in known}
    for key in extra:
        log.warning("%s: section [%s] is not part of this schema yet; kept unread", path, key)
    cell = root.table("cell")
    name = cell.text("name")
    cell.done()
    camera = _camera(root.table("camera"))
    part = _part(root.table("part"))
    reference = _reference(root.table("reference"))
    poses = _measuring_poses(root, reference, camera, len(part.points_w))
    tracker = _tracker(root.table("tracker")) if "tracker" in raw else None
    sim = _sim(root.table("sim")) if "sim" in raw else None
    if camera.backend == "sim" and sim is None:
        raise ConfigError(f"{path}: [camera] backend = 'sim' needs a [sim] section")
    if tracker is not None and tracker.backend == "sim" and sim is None:
        raise ConfigError(f"{path}: [tracker] backend = 'sim' needs a [sim] section")
    return CellConfig(path, name, camera, part, reference, poses, tracker, sim, extra)


def default_sim_state_file() -> Path:
    """Where ``monoguide sim-cell`` says where its devices listen, unless ``[sim] state_file`` says otherwise."""
    run_dir = os.environ.get("XDG_RUNTIME_DIR") or f"/tmp/monoguide-{os.getuid()}"
    return Path(run_dir) / "monoguide-sim-cell.json"


# --- sections ----------------------------------------------------------------------------------


def _camera(t: _Table) -> CameraConfig:
    backend = t.choice("backend", CAMERA_BACKENDS)
    intr = t.table("intrinsics")
    try:
        model = CameraModel.from_dict(dict(intr.raw), where=intr.where)
    except RecordError as exc:
        raise ConfigError(str(exc)) from exc
    intr.raw.clear()
    cti = t.path("cti", None)
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


def _part(t: _Table) -> PartConfig:
    points = t.points("points_w")
    names = t.texts("point_names", tuple(f"P{i + 1}" for i in range(len(points))))
    if len(names) != len(points):
        raise ConfigError(f"{t.where}.point_names: {len(names)} names for {len(points)} points_w")
    out = PartConfig(points, t.number("hole_radius_mm", positive=True), names)
    t.done()
    return out


def _reference(t: _Table) -> ReferenceConfig:
    out = ReferenceConfig(t.matrix("T_cf_w0"), t.matrix("T_cf_b", None))
    t.done()
    return out


def _measuring_poses(root: _Table, ref: ReferenceConfig, cam: CameraConfig, n_points: int) -> tuple:
    entries = root.raw.pop("measuring_poses", None)
    where = f"{root.where}: [[measuring_poses]]"
    if not isinstance(entries, list) or not entries:
        raise ConfigError(f"{where}: at least one measuring pose is needed, got {entries!r}")
    poses = []
    for i, entry in enumerate(entries):
        t = _Table(entry, f"{root.where}: [[measuring_poses]] #{i + 1}", root.base, nested=True)
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


def _tracker(t: _Table) -> TrackerConfig:
    backend = t.choice("backend", TRACKER_BACKENDS)
    port = t.text("port", None)
    if backend == "serial" and not port:
        raise ConfigError(f"{t.where}.port: backend 'serial' needs the serial port (e.g. /dev/ttyUSB0)")
    baud = t.integer("baud", 115200, minimum=1)
    out = TrackerConfig(backend, port, baud, t.number("timeout_s", 2.0, positive=True))
    t.done()
    return out


def _sim(t: _Table) -> SimConfig:
    dev = t.table("deviation") if "deviation" in t.raw else _Table({}, f"{t.where}.deviation", t.base)
    bench = t.table("benchmarks") if "benchmarks" in t.raw else _Table({}, f"{t.where}.benchmarks", t.base)
    benchmarks = {k: bench.vector(k, 3) for k in list(bench.raw)}
    targets = []
    for i, entry in enumerate(t.raw.pop("targets", [])):
        tt = _Table(entry, f"{t.where}.targets #{i + 1}", t.base, nested=True)
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
        tracker_noise_mm=t.number("tracker_noise_mm", 0.025, nonnegative=True),
        exposure_us_nominal=t.number("exposure_us_nominal", 8000.0, positive=True),
        benchmarks=benchmarks,
        tool_smr_f=t.vector("tool_smr_f", 3, None),
        targets=tuple(targets),
    )
    dev.done()
    t.done()
    return out


# --- private: typed access that names the key ---------------------------------------------------

_MISSING = object()


class _Table:
    """One TOML table being read; every getter pops its key, :meth:`done` rejects what is left."""

    def __init__(self, raw: Any, where: str, base: Path, nested: bool = False) -> None:
        if not isinstance(raw, dict):
            raise ConfigError(f"{where}: expected a table, got {raw!r}")
        self.raw = dict(raw)
        self.where = where
        self.base = base
        self.nested = nested

    def table(self, key: str) -> _Table:
        where = f"{self.where}.{key}" if self.nested else f"{self.where}: [{key}]"
        return _Table(self._pop(key, _MISSING), where, self.base, nested=True)

    def done(self) -> None:
        if self.raw:
            raise ConfigError(f"{self.where}: unknown key(s) {sorted(self.raw)}")

    def text(self, key: str, default: Any = _MISSING) -> Any:
        value = self._pop(key, default)
        if value is default and default is not _MISSING:
            return value
        if not isinstance(value, str):
            raise ConfigError(f"{self.where}.{key} = {value!r}: expected a string")
        return value

    def texts(self, key: str, default: Any = _MISSING) -> Any:
        value = self._pop(key, default)
        if value is default and default is not _MISSING:
            return value
        if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
            raise ConfigError(f"{self.where}.{key} = {value!r}: expected a list of strings")
        return tuple(value)

    def choice(self, key: str, options: tuple[str, ...]) -> str:
        value = self.text(key)
        if value not in options:
            raise ConfigError(f"{self.where}.{key} = {value!r}: must be one of {list(options)}")
        return value

    def path(self, key: str, default: Any = _MISSING) -> Any:
        value = self.text(key, default)
        if value is default and default is not _MISSING:
            return value
        p = Path(os.path.expandvars(os.path.expanduser(value)))
        return p if p.is_absolute() else self.base / p

    def number(self, key: str, default: Any = _MISSING, positive: bool = False, nonnegative: bool = False) -> Any:
        value = self._pop(key, default)
        if value is default and default is not _MISSING:
            return value
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise ConfigError(f"{self.where}.{key} = {value!r}: expected a finite number")
        if positive and value <= 0:
            raise ConfigError(f"{self.where}.{key} = {value!r}: must be positive")
        if nonnegative and value < 0:
            raise ConfigError(f"{self.where}.{key} = {value!r}: must not be negative")
        return float(value)

    def integer(self, key: str, default: Any = _MISSING, minimum: int | None = None) -> Any:
        value = self._pop(key, default)
        if value is default and default is not _MISSING:
            return value
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{self.where}.{key} = {value!r}: expected an integer")
        if minimum is not None and value < minimum:
            raise ConfigError(f"{self.where}.{key} = {value!r}: must be at least {minimum}")
        return value

    def ints(self, key: str, length: int | None, default: Any = _MISSING) -> Any:
        value = self._pop(key, default)
        if value is default and default is not _MISSING:
            return value
        ok = isinstance(value, list) and all(isinstance(v, int) and not isinstance(v, bool) for v in value)
        if not ok or (length is not None and len(value) != length):
            raise ConfigError(f"{self.where}.{key} = {value!r}: expected a list of {length or 'n'} integers")
        return tuple(value)

    def vector(self, key: str, length: int, default: Any = _MISSING) -> Any:
        value = self._pop(key, default)
        if value is default and default is not _MISSING:
            return value if value is None else np.asarray(value, dtype=float)
        arr = self._array(key, value)
        if arr.shape != (length,):
            raise ConfigError(f"{self.where}.{key} = {value!r}: expected {length} numbers")
        return arr

    def points(self, key: str) -> np.ndarray:
        value = self._pop(key, _MISSING)
        arr = self._array(key, value)
        if arr.ndim != 2 or arr.shape[1] != 3 or len(arr) == 0:
            raise ConfigError(f"{self.where}.{key} = {value!r}: expected a list of [x, y, z] points (mm)")
        return arr

    def matrix(self, key: str, default: Any = _MISSING) -> Any:
        value = self._pop(key, default)
        if value is default and default is not _MISSING:
            return value
        T = self._array(key, value)
        if T.shape != (4, 4):
            raise ConfigError(f"{self.where}.{key}: expected a 4x4 matrix (4 rows of 4), got shape {T.shape}")
        if not np.allclose(T[3], [0, 0, 0, 1]):
            raise ConfigError(f"{self.where}.{key}: last row must be [0, 0, 0, 1], got {T[3].tolist()}")
        R = T[:3, :3]
        defect = float(np.max(np.abs(R.T @ R - np.eye(3))))
        if defect > MATRIX_TOL or np.linalg.det(R) < 0:
            raise ConfigError(f"{self.where}.{key}: rotation part is not a rotation (|R^T R - I| = {defect:.2g}, "
                              f"det = {np.linalg.det(R):.4f})")
        T = T.copy()
        T[:3, :3] = orthonormalize(R)
        return T

    def _array(self, key: str, value: Any) -> np.ndarray:
        try:
            arr = np.asarray(value, dtype=float)
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"{self.where}.{key} = {value!r}: expected numbers") from exc
        if not np.all(np.isfinite(arr)):
            raise ConfigError(f"{self.where}.{key} = {value!r}: numbers must be finite")
        return arr

    def _pop(self, key: str, default: Any) -> Any:
        if key in self.raw:
            return self.raw.pop(key)
        if default is _MISSING:
            raise ConfigError(f"{self.where}.{key}: missing")
        return default
