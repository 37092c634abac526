"""The cell config a ``monoguide simulate`` run uses: the given simulated cell, adjusted for this run.

``derive_config`` reads the source config (``config/sim-cell.toml`` by default), changes only what the run
asks for — ``[sim] seed``, ``[robot] backend`` (``sim-ur`` or ``sim-kuka``, with its port), ``[sim]
repeatability_*`` (0 with ``--perfect-robot``), the robot's and the PLC's ``host`` (a loopback address of
their own, so two runs never collide), ``[sim] state_file`` (in the run's work directory), ``[sim]
reported_repeatability_fraction`` (0 unless the source sets it: the robot's report sees none of its
repeatability, the worst case) — and writes it
as TOML text into the work directory. The service and the simulated cell then read that file exactly as a
line's ``monoguide run`` reads ``/etc/monoguide/cell.toml``.

With ``--calibration CELL.toml`` the service reads a second file, ``service.toml``: the same, with the
calibration values of ``CELL.toml`` (``[camera.intrinsics]``, ``[camera] T_f_c``, ``[reference] T_cf_b`` and
``T_cf_w0``, each part type's ``T_cf_w0``, each ``[[measuring_poses]]`` ``T_cf_si`` and ``[[reference_marks]]``
``position_cf`` by name), its ``[calibration]`` provenance (so that a part type the wizard has not calibrated is
refused, ``PART_NOT_CALIBRATED``, before anything moves, as ``run`` on that file does) and ``[sim] truth_config``
naming ``cell.toml``:
the service believes the calibration, the simulated devices (the camera in the service's process too) keep
the truth of ``--config``.

:func:`predicted_grasp_sigma` is the layout's predicted sigma at the grasp point for the run's cell, with
the part of the robot's repeatability that its reported pose does not see (the camera pose error the
service cannot correct).

The derived configs are written with tomlkit (:func:`dumps_toml`): every value exactly as read, the matrices
one row per line; comments of the source are not carried over.
"""

from __future__ import annotations

import dataclasses
import json
import random
import socket
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import tomlkit
import tomlkit.exceptions

from monoguide.daemon.config import load_cell_config, read_config_toml
from monoguide.daemon.plan import cell_layout
from monoguide.drivers.atomic_file import write_atomic
from monoguide.drivers.errors import ConfigError
from monoguide.drivers.toml_format import matrix
from monoguide.solver.planning import assess_layout

ROBOTS = {"ur": ("sim-ur", 30004), "kuka": ("sim-kuka", 54600)}
AUTO_HOST_NET = "127.77.0"  # a run without --host picks a free address 127.77.0.1 .. 127.77.0.254
FAULT_TIMEOUTS = {  # --faults: shorter waits than a line's, so that a stalled device costs seconds, not minutes
    "robot": {"move_timeout_s": 4.0, "ack_timeout_s": 1.5},
    "plc": {"ack_timeout_s": 3.0},
}
REPORTED_FRACTION = 0.0  # [sim] reported_repeatability_fraction of a run whose config does not set it


@dataclass(frozen=True)
class DerivedCell:
    """Where one run's files are: the config the children read, the service's state directory, the logs."""

    config: Path
    state_dir: Path
    truth_log: Path
    sim_state: Path
    host: str
    data: dict[str, Any]
    service_config: Path | None = None  # the service's config when it differs (--calibration); else ``config``
    calibration: dict[str, Any] | None = None  # {"path": CELL.toml, "values": [the keys taken from it]}
    jobs: tuple[int, ...] = (1,)  # the part types the line brings, in turn

    @property
    def service(self) -> Path:
        """The config the service reads."""
        return self.service_config or self.config

    @property
    def plc_port(self) -> int:
        return int(self.data["plc"].get("port", 502))

    @property
    def plc_unit(self) -> int:
        return int(self.data["plc"].get("unit", 1))


def derive_config(source: Path, work_dir: Path, *, seed: int | None = None, robot: str | None = None,
                  perfect_robot: bool = False, host: str | None = None, faults: bool = False,
                  calibration: Path | None = None, jobs: tuple[int, ...] = ()) -> DerivedCell:
    """Write ``work_dir/cell.toml``, the run's config derived from ``source`` (and ``work_dir/service.toml``
    with ``calibration``); see the module's doc."""
    data = _read_toml(source, "--config")
    for section in ("robot", "plc", "sim"):
        if not isinstance(data.get(section), dict):
            raise ConfigError(f"--config {source}: no [{section}] section; simulate needs a simulated cell "
                              f"(config/sim-cell.toml) with a simulated robot and a PLC")
    backend = str(data["robot"].get("backend", ""))
    if not backend.startswith("sim-"):
        raise ConfigError(f"--config {source}: [robot].backend = {backend!r}: simulate needs 'sim-ur' or 'sim-kuka'")
    if robot is not None:
        if robot not in ROBOTS:
            raise ConfigError(f"--robot {robot}: expected one of {', '.join(ROBOTS)}")
        data["robot"]["backend"], data["robot"]["port"] = ROBOTS[robot]
    data["plc"].setdefault("port", 502)
    robot_port = int(data["robot"].get("port", ROBOTS[data["robot"]["backend"].removeprefix("sim-")][1]))
    host = host or pick_free_host((robot_port, int(data["plc"]["port"])))
    data["robot"]["host"] = host
    data["plc"]["host"] = host
    sim = data["sim"]
    if seed is not None:
        sim["seed"] = int(seed)
    # the robot's reported pose sees none of a stop's deviation unless the config says otherwise: the worst case
    sim.setdefault("reported_repeatability_fraction", REPORTED_FRACTION)
    if perfect_robot:
        sim["repeatability_mm"] = 0.0
        sim["repeatability_deg"] = 0.0
    work_dir = Path(work_dir).resolve()
    work_dir.mkdir(parents=True, exist_ok=True)
    sim_state = work_dir / "sim-state.json"
    sim["state_file"] = str(sim_state)
    if faults:
        for section, values in FAULT_TIMEOUTS.items():
            for key, value in values.items():
                data[section][key] = min(float(data[section].get(key, value)), value)
    config = work_dir / "cell.toml"
    write_atomic(config, dumps_toml(data, f"derived by `monoguide simulate` from {Path(source).resolve()}"))
    cell = DerivedCell(config, work_dir / "state", work_dir / "truth.jsonl", sim_state, host, data,
                       jobs=_jobs(load_cell_config(config), jobs))
    if calibration is None:
        return cell
    service_data, taken = with_calibration(data, _read_toml(calibration, "--calibration"), calibration)
    service_data["sim"]["truth_config"] = str(config)
    service = work_dir / "service.toml"
    write_atomic(service, dumps_toml(service_data, f"derived by `monoguide simulate` from {Path(source).resolve()} "
                                                   f"with the calibration of {Path(calibration).resolve()}"))
    load_cell_config(service)  # the service must be able to read it
    return dataclasses.replace(cell, service_config=service,
                               calibration={"path": str(Path(calibration).resolve()), "values": taken})


CALIBRATION_KEYS = (("camera", "T_f_c"), ("reference", "T_cf_b"), ("reference", "T_cf_w0"))


def with_calibration(truth: dict[str, Any], calibrated: dict[str, Any], path: Path) -> tuple[dict[str, Any],
                                                                                              list[str]]:
    """``truth`` (a cell config's TOML data) with the calibration values of ``calibrated``: the data, and the
    keys taken (``camera.intrinsics``, ``camera.T_f_c``, ``reference.T_cf_b``, ``reference.T_cf_w0``,
    ``parts.<job>.T_cf_w0``, ``measuring_poses.<name>.T_cf_si``, ``reference_marks.<name>.position_cf``) and its
    ``[calibration]`` provenance (``calibration``; none when ``calibrated`` has none). A value ``calibrated`` lacks
    stays the truth's."""
    data = json.loads(json.dumps(truth))  # a deep copy (TOML data is JSON data)
    taken = []
    camera = calibrated.get("camera", {})
    if isinstance(camera.get("intrinsics"), dict):
        data.setdefault("camera", {})["intrinsics"] = camera["intrinsics"]
        taken.append("camera.intrinsics")
    for section, key in CALIBRATION_KEYS:
        value = calibrated.get(section, {}).get(key)
        if value is not None:
            data.setdefault(section, {})[key] = value
            taken.append(f"{section}.{key}")
    parts = {p.get("job"): p for p in data.get("parts", [])}
    for part in calibrated.get("parts", []):
        if "T_cf_w0" in part and part.get("job") in parts:
            parts[part["job"]]["T_cf_w0"] = part["T_cf_w0"]
            taken.append(f"parts.{part['job']}.T_cf_w0")
    poses = {p.get("name"): p for p in data.get("measuring_poses", [])}
    for pose in calibrated.get("measuring_poses", []):
        name = pose.get("name")
        if "T_cf_si" not in pose:
            continue
        if name not in poses:
            raise ConfigError(f"--calibration {path}: measuring pose {name!r} is not one of the cell's "
                              f"({', '.join(str(n) for n in poses)})")
        poses[name]["T_cf_si"] = pose["T_cf_si"]
        taken.append(f"measuring_poses.{name}.T_cf_si")
    marks = {m.get("name"): m for m in data.get("reference_marks", [])}
    for mark in calibrated.get("reference_marks", []):
        if "position_cf" in mark and mark.get("name") in marks:  # surveyed by the wizard's marks step
            marks[mark["name"]]["position_cf"] = mark["position_cf"]
            taken.append(f"reference_marks.{mark['name']}.position_cf")
    if not taken:
        raise ConfigError(f"--calibration {path}: no calibration values in it ([camera.intrinsics], [camera] T_f_c, "
                          f"[reference] T_cf_b / T_cf_w0, [[measuring_poses]] T_cf_si)")
    # the wizard's provenance says which part types it calibrated: the service refuses the others before anything
    # moves (PART_NOT_CALIBRATED), as `monoguide run` on that file does; a file without one was entered by hand
    data.pop("calibration", None)
    if isinstance(calibrated.get("calibration"), dict):
        data["calibration"] = calibrated["calibration"]
        taken.append("calibration")
    return data, taken


def predicted_grasp_sigma(config: Path, repeatability_mm: float, repeatability_deg: float,
                          job: int | None = None) -> dict[str, Any]:
    """The layout's predicted sigma of the part pose at the grasp point (``sigma_mm``, ``sigma_deg``; the principal
    variances of its covariance, ``variances_mm2``, ``variances_deg2``, the shape the grasp target needs) for the
    measuring poses of ``config`` (``[layout]`` sigma_px), with the robot's repeatability ``repeatability_mm`` /
    ``repeatability_deg`` per axis at the flange, carried to the camera through ``[camera] T_f_c`` (what
    ``monoguide plan --layout`` prints as "with the robot's repeatability"); None when the layout leaves the pose
    undetermined. ``job``: of that part type (None: the config's first)."""
    cell = load_cell_config(config)
    layout = cell_layout(cell if job is None else cell.for_job(job))
    request = dataclasses.replace(layout.request, repeatability_mm=repeatability_mm,
                                  repeatability_deg=repeatability_deg)
    assessed = assess_layout(request, layout.T_w0_si, layout.observed)
    sigmas = assessed.sigmas_with_repeatability if repeatability_mm or repeatability_deg else assessed.sigmas
    if sigmas is None:
        return {"sigma_mm": None, "sigma_deg": None, "sigma_px": request.sigma_px}
    return {"sigma_mm": sigmas.sigma_trans_mm, "sigma_deg": sigmas.sigma_rot_deg, "sigma_px": request.sigma_px,
            "variances_mm2": sigmas.grasp_variances_mm2, "variances_deg2": sigmas.rotation_variances_deg2}


def _jobs(config: Any, asked: tuple[int, ...]) -> tuple[int, ...]:
    """``--jobs``: the part types the line brings in turn, each one of the config's; default all of them."""
    if bad := [job for job in asked if job not in config.jobs]:
        raise ConfigError(f"--jobs {','.join(map(str, asked))}: {bad} not among the jobs of {config.path} "
                          f"({', '.join(p.describe() for p in config.parts)})")
    return asked or config.jobs


def _read_toml(path: Path, option: str) -> dict[str, Any]:
    return read_config_toml(path, "cell config", label=f"{option} {path}")  # a regular file of at most 4 MiB


def pick_free_host(ports: tuple[int, ...], net: str = AUTO_HOST_NET) -> str:
    """A loopback address ``net.1 .. net.254`` where every one of ``ports`` can be bound now."""
    start = random.randrange(254)
    for k in range(254):
        host = f"{net}.{(start + k) % 254 + 1}"
        if all(port_free(host, port) for port in ports):
            return host
    raise ConfigError(f"no free loopback address {net}.1-254 for ports {ports}; give --host")


def port_free(host: str, port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as the simulated devices bind
        try:
            s.bind((host, port))
        except OSError:
            return False
    return True


# --- TOML text ----------------------------------------------------------------------------------


def dumps_toml(data: dict[str, Any], comment: str | None = None) -> str:
    """TOML text for ``data`` (what :func:`tomllib.loads` returns for a cell config), ``comment`` (lines) at its
    top: ``loads(dumps(d)) == d``. Written with tomlkit; a matrix (a list of lists of numbers) one row per line,
    its numbers exactly as they are (a derived config is the source's values, not a rounding of them)."""
    doc = tomlkit.document()
    for line in comment.splitlines() if comment else ():
        doc.add(tomlkit.comment(line))
    try:
        doc.update(_readable(data))
        return doc.as_string()
    except (TypeError, ValueError, tomlkit.exceptions.TOMLKitError) as exc:
        raise ConfigError(f"cannot write the derived config as TOML: {exc}") from exc


def _readable(value: Any) -> Any:
    if isinstance(value, dict):
        return {key: _readable(v) for key, v in value.items()}
    if isinstance(value, list):
        if value and all(isinstance(row, list) and row and all(_is_number(v) for v in row) for row in value):
            return matrix(value, decimals=None)
        return [_readable(v) for v in value]
    return value


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)
