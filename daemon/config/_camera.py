"""``[camera]`` and ``[camera.intrinsics]``: which camera, how it is set up, and its calibrated model."""

from __future__ import annotations

from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from monoguide.daemon.config._bounds import bounded_integer, bounded_number
from monoguide.daemon.config._reader import ConfigTable
from monoguide.drivers.errors import ConfigError
from monoguide.solver.camera import CameraModel
from monoguide.solver.errors import RecordError

CAMERA_BACKENDS = ("genicam", "sim")
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


def read_camera(t: ConfigTable) -> CameraConfig:
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
        exposure_us=bounded_number(t, "exposure_us", None),
        gain_db=t.number("gain_db", None),
        region=region,
        grab_timeout_s=bounded_number(t, "grab_timeout_s", 2.0),
        T_f_c=t.matrix("T_f_c", None),
    )
    t.done()
    return out


def _intrinsics(t: ConfigTable) -> CameraModel:
    """Every coefficient is required: a camera calibrated without distortion says ``k1 = 0.0``."""
    values = {key: bounded_integer(t, key) if key in ("width", "height") else t.number(key) for key in INTRINSICS_KEYS}
    t.done()
    try:
        return CameraModel.from_dict(values, where=t.where)
    except RecordError as exc:
        raise ConfigError(exc.message) from exc
