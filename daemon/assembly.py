"""The one place where the cell's devices are built from its config, real or simulated.

Runtime code asks this module for a :class:`~monoguide.drivers.camera.Camera` or a
:class:`~monoguide.drivers.tracker.LaserTracker` and never learns which back-end it holds. The simulated
back-ends read a :class:`SimCell` built here from the same config; the simulated tracker runs as its own
process (``monoguide sim-cell``), which writes where it listens into a small JSON state file.

This is the only module of the daemon allowed to import ``monoguide.drivers.sim`` (the import-linter
contract in ``pyproject.toml``), and it does so inside the builders, only when the config asks for a
simulated back-end: a real cell never loads the simulator or its renderer.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

from monoguide.daemon.config import CellConfig, default_sim_state_file, load_cell_config
from monoguide.daemon.errors import ConfigMissingKey
from monoguide.drivers.atomic_file import write_atomic
from monoguide.drivers.camera import Camera, CameraSettings
from monoguide.drivers.errors import ConfigError, DeviceNotFound
from monoguide.drivers.genicam_camera import GenICamCamera
from monoguide.drivers.modbus_plc import ModbusPlc
from monoguide.drivers.plc import Plc
from monoguide.drivers.robot import Robot
from monoguide.drivers.tracker import LaserTracker, SerialLaserTracker

if TYPE_CHECKING:
    from monoguide.drivers.sim.cell import SimCell, SimCellSpec

SIM_STATE_FORMAT = "monoguide.sim-cell-state/1"


def camera_settings(config: CellConfig) -> CameraSettings:
    """The settings the cell wants on its camera (from ``[camera]``)."""
    c = config.camera
    return CameraSettings(c.pixel_format, c.exposure_us, c.gain_db, c.region)


def build_camera(config: CellConfig, sim_cell: SimCell | None = None, state_file: Path | None = None) -> Camera:
    """The cell's camera, not yet opened. The simulated one reads ``sim_cell`` (built from config if None).

    In a cell whose robot is simulated too (``[robot] backend = "sim-*"``) the simulated camera follows that
    robot: before every grab it stands where the sim-cell's controller has its robot and sees the part its
    part supply presents, and it takes up the ``camera`` faults commanded to sim-cell; both are found through
    the sim-cell state file (``state_file``, default ``[sim] state_file``)."""
    c = config.camera
    if c.backend == "genicam":
        assert c.cti is not None  # the config loader insists
        return GenICamCamera(c.cti, serial=c.serial, user_name=c.user_name)
    from monoguide.drivers.sim.camera import SimCamera  # only a simulated cell loads the simulator

    follow = None
    if config.robot is not None and config.robot.simulated:
        follow = state_file or sim_state_file(config)
    return SimCamera(sim_cell if sim_cell is not None else build_sim_cell(config), follow=follow)


def build_tracker(config: CellConfig, state_file: Path | None = None) -> LaserTracker:
    """The cell's laser tracker, not yet opened. The simulated one is found through the state file of a
    running ``monoguide sim-cell``."""
    t = config.tracker
    if t is None:
        raise ConfigMissingKey(f"{config.path}: [tracker]: missing section")
    if t.backend == "serial":
        assert t.port is not None  # the config loader insists
        return SerialLaserTracker(t.port, t.baud, t.timeout_s)
    path = state_file or sim_state_file(config)
    port = read_sim_state(path).get("tracker", {}).get("port")
    if not port:
        raise DeviceNotFound(f"simulated tracker: {path} names no tracker port")
    return SerialLaserTracker(port, t.baud, t.timeout_s)


def build_robot(config: CellConfig, state_file: Path | None = None) -> Robot:
    """The cell's robot, not yet opened: UR over RTDE or KUKA over its XML channel. A simulated controller
    speaks the same protocol; where it listens is read from the state file of a running ``monoguide sim-cell``.
    The adapter checks each in-position report against the taught flange poses the config implies."""
    from monoguide.drivers.kuka_robot import KukaRobot
    from monoguide.drivers.ur_robot import UrRobot

    r = config.robot
    if r is None:
        raise ConfigMissingKey(f"{config.path}: [robot]: missing section")
    host, port = r.host, r.port
    if r.simulated:
        path = state_file or sim_state_file(config)
        listens = read_sim_state(path).get("robot", {})
        if listens.get("backend") != r.backend or not listens.get("host"):
            raise DeviceNotFound(f"simulated robot: {path} names no {r.backend} controller (is sim-cell running "
                                 f"with this config?)")
        host, port = str(listens["host"]), int(listens["port"])
    timeouts = {"connect_timeout_s": r.connect_timeout_s, "move_timeout_s": r.move_timeout_s,
                "ack_timeout_s": r.ack_timeout_s, "stale_timeout_s": r.stale_timeout_s,
                "T_b_f_taught": config.cell_taught_flange_poses(), "pose_tolerance_mm": r.pose_tolerance_mm,
                "pose_tolerance_deg": r.pose_tolerance_deg}
    if r.make == "ur":
        return UrRobot(host, port, frequency_hz=r.rtde_frequency_hz, **timeouts)
    return KukaRobot(host, port, **timeouts)


def build_plc(config: CellConfig) -> Plc:
    """The line's PLC, not yet connected: Modbus TCP where ``[plc]`` says (the simulated PLC of
    ``monoguide sim-cell`` listens exactly there too)."""
    p = config.plc
    if p is None:
        raise ConfigMissingKey(f"{config.path}: [plc]: missing section")
    return ModbusPlc(p.host, p.port, p.unit, p.base, p.word_order, p.timeout_s)  # type: ignore[arg-type]


def sim_cell_spec(config: CellConfig) -> SimCellSpec:
    """The simulated cell's definition from the cell config (``[sim]`` with the shared sections). With ``[sim]
    truth_config`` the cell is that file's: this file's calibration values are then only what the service
    believes (``monoguide simulate --calibration``), the simulated devices keep the truth (the reference marks
    too: the truth config's ``[[reference_marks]]`` are where the marks are). The parts' ``outline_w`` go along:
    the simulated camera does not see a mark the part's sheet hides."""
    from monoguide.drivers.sim.cell import SimCellSpec, SimMark, SimPartType, SimTarget

    sim = config.sim
    if sim is None:
        raise ConfigError(f"{config.path}: the simulated cell needs a [sim] section")
    if sim.truth_config is not None:
        truth = load_cell_config(sim.truth_config)
        if truth.sim is None or truth.sim.truth_config is not None:
            raise ConfigError(f"{config.path}: [sim] truth_config = {sim.truth_config}: expected a simulated cell "
                              f"config with a [sim] section and no truth_config of its own")
        return sim_cell_spec(truth)
    if config.reference.T_cf_b is None:
        raise ConfigError(f"{config.path}: [reference] T_cf_b: the simulated robot needs its base pose")
    return SimCellSpec(
        camera=config.camera.intrinsics,
        points_w=config.part.points_w,
        hole_radius_mm=config.part.hole_radius_mm,
        T_cf_w0=config.reference.T_cf_w0,
        T_cf_b=config.reference.T_cf_b,
        T_cf_si=tuple(p.T_cf_si for p in config.cell_poses),
        T_f_c=sim.T_f_c,
        point_names=config.part.point_names,
        T_cf_tracker=sim.T_cf_tracker,
        seed=sim.seed,
        deviation_translation_mm=sim.deviation_translation_mm,
        deviation_rotation_deg=sim.deviation_rotation_deg,
        repeatability_mm=sim.repeatability_mm,
        repeatability_deg=sim.repeatability_deg,
        reported_repeatability_fraction=sim.reported_repeatability_fraction,
        tracker_noise_mm=sim.tracker_noise_mm,
        exposure_us_nominal=sim.exposure_us_nominal,
        benchmarks_cf=dict(sim.benchmarks),
        tool_smr_f=sim.tool_smr_f,
        targets=tuple(SimTarget(t.name, t.T_cf_t, t.points_t) for t in sim.targets),
        focus_distance_mm=sim.focus_distance_mm,
        aperture_mm=sim.aperture_mm,
        target_marks=config.calibration_target.marks if config.calibration_target is not None else None,
        part_types=tuple(SimPartType(p.job, p.part.points_w, p.part.hole_radius_mm, p.T_cf_w0, p.part.point_names,
                                     p.measuring_poses[0].number, p.part.outline_w) for p in config.parts),
        marks=tuple(SimMark(m.name, m.position_cf, m.radius_mm, m.normal_cf) for m in config.reference_marks),
        outline_w=config.part.outline_w,
    )


def build_sim_cell(config: CellConfig) -> SimCell:
    """A fresh simulated cell (seeded from ``[sim] seed``)."""
    from monoguide.drivers.sim.cell import SimCell

    return SimCell(sim_cell_spec(config))


def build_sim_operator(cell: SimCell, targets: Path | None, robot_truth: Path | None, seed: int) -> Any:
    """The simulated person at the cell of ``monoguide calibrate --sim`` (the wizard's operator protocol):
    acts on ``cell``'s scene and rewrites the simulated tracker's ``targets`` file (the flange SMR following
    the controller's ``robot_truth``)."""
    from monoguide.drivers.sim.calibration_scene import SimOperator

    return SimOperator(cell, targets, robot_truth, seed)


def sim_state_file(config: CellConfig) -> Path:
    """Where ``sim-cell`` writes (and ``probe`` reads) where the simulated devices listen."""
    if config.sim is not None and config.sim.state_file is not None:
        return config.sim.state_file
    return default_sim_state_file()


def write_sim_state(path: Path, state: dict[str, Any]) -> None:
    """Write the state file atomically (a reader never sees half a file)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(path, json.dumps({"format": SIM_STATE_FORMAT, **state}, indent=1))


def read_sim_state(path: Path) -> dict[str, Any]:
    """The state of a running ``monoguide sim-cell``; :class:`DeviceNotFound` when there is none."""
    try:
        state = json.loads(Path(path).read_text())
    except FileNotFoundError as exc:
        raise DeviceNotFound(f"no simulated cell running: {path} does not exist (start `monoguide sim-cell`)") \
            from exc
    except (OSError, ValueError) as exc:
        raise DeviceNotFound(f"simulated cell state {path} unreadable: {exc}") from exc
    if state.get("format") != SIM_STATE_FORMAT:
        raise DeviceNotFound(f"{path}: not a sim-cell state file (format {state.get('format')!r})")
    pid = state.get("pid")
    if isinstance(pid, int) and not _alive(pid):
        raise DeviceNotFound(f"simulated cell of {path} (pid {pid}) is no longer running")
    return state


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True
