"""``monoguide calibrate --sim``: the calibration wizard's rig on the simulated cell, over the real transports.

:func:`open_sim_rig` makes a cell "before calibration" and everything the wizard needs to calibrate it:

- ``work_dir/cell.toml``: the truth config with its calibration values perturbed (seeded; intrinsics f ±1.5 %,
  cx cy ±20 px, no distortion; ``T_cf_b`` and ``T_cf_w0`` 5 mm / 0.3°, each ``T_cf_si`` 3 mm / 0.3°, ``T_f_c``
  2 mm / 0.2°, each ``[[reference_marks]] position_cf`` 3 mm), the measuring poses' taught flange poses ``T_b_f``
  as the robot program has them, the ``[cell_frame]`` and ``[calibration_target]`` nominals, and a ``[sim]``
  section stripped of the truth. That file is what the wizard calibrates; the truth stays in the truth config.
- ``monoguide sim-cell --no-plc`` for the truth config (on loopback ``host``, its state file and log in
  ``work_dir``) as a child process that dies with the wizard (``_sim_process``): the simulated tracker behind
  its pty and the simulated robot controller (UR or KUKA, as ``[robot] backend`` says) with its
  base-calibration poses.
- the tracker and the robot adapters (``daemon.assembly``, from sim-cell's state file), the simulated camera
  in this process following sim-cell's robot, and the simulated operator acting on the scene the camera
  renders and the tracker measures (``drivers/sim/calibration_scene.py``).
- ``truth_errors(step, result, earlier)``: each step's result against the truth config (``_sim_truth``).

A part type's session (``--job N``) calibrates the config the cell's session made (``calibrating``), as part type
``N`` sees it, with a part of type ``N`` in the simulated cell.
"""

from __future__ import annotations

import contextlib
import math
import tomllib
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from monoguide.daemon.assembly import (
    build_camera,
    build_robot,
    build_sim_cell,
    build_sim_operator,
    build_tracker,
    camera_settings,
    read_sim_state,
)
from monoguide.daemon.calibrate._rig import CalibrationOptions, CalibrationRig, quiet
from monoguide.daemon.calibrate._sim_process import SimCellProcess
from monoguide.daemon.calibrate._sim_truth import truth_error_function
from monoguide.daemon.config import CellConfig, load_cell_config
from monoguide.daemon.errors import SimRigConfigError
from monoguide.daemon.simulate import derive_config, dumps_toml
from monoguide.solver.calibration.target import default_target_marks
from monoguide.solver.frames import compose, invert, make_T, rotvec_to_matrix

FOCAL_REL = 0.015  # the perturbation of the calibration values: what "before calibration" means here
PRINCIPAL_PX = 20.0
POSE_PERTURBATION = {"T_cf_b": (5.0, 0.3), "T_cf_w0": (5.0, 0.3), "T_cf_si": (3.0, 0.3), "T_f_c": (2.0, 0.2)}
MARK_PERTURBATION_MM = 3.0  # each reference mark's nominal off its true centre by this (within the marks step's 5 mm)


@contextmanager
def open_sim_rig(truth_config: Path, work_dir: Path, options: CalibrationOptions, *, seed: int = 1,
                 host: str | None = None, progress: Callable[[str], None] = quiet, job: int | None = None,
                 calibrating: Path | None = None) -> Iterator[CalibrationRig]:
    """The rig of ``monoguide calibrate --sim`` (see the module's doc); every device closed and the simulated
    cell stopped on leaving, however it is left. ``job``: part type ``job``'s rig on the config ``calibrating``
    (the cell's session's; default: a new cell before calibration in ``work_dir``)."""
    work_dir = Path(work_dir).resolve()
    work_dir.mkdir(parents=True, exist_ok=True)
    derived = derive_config(Path(truth_config), work_dir / "sim-cell", host=host)
    truth = load_cell_config(derived.config)
    _check_truth(truth)
    if calibrating is None:
        config_path = write_before_calibration(truth, derived.data, work_dir / "cell.toml", seed)
        progress(f"the cell before calibration: {config_path} (truth: {Path(truth_config).resolve()})")
    else:
        config_path = Path(calibrating)
    config = load_cell_config(config_path)
    if job is not None:
        config, truth = config.for_job(job), truth.for_job(job)
        progress(f"part type {job} ({config.part_name}) of {config_path} (truth: {Path(truth_config).resolve()})")
    progress(f"starting the simulated cell on {derived.host} (log {work_dir / 'sim-cell.log'})")
    with SimCellProcess(derived.config, work_dir / "sim-cell.log") as child, contextlib.ExitStack() as devices:
        child.wait_listening()
        state = read_sim_state(derived.sim_state)
        cell = build_sim_cell(truth)
        if job is not None:
            cell.set_part_type(job)  # the part the line supplies is of this type
        operator = build_sim_operator(cell, Path(state["tracker"]["targets"]), Path(state["robot"]["truth"]), seed)
        tracker = build_tracker(truth, derived.sim_state)
        robot = build_robot(config, derived.sim_state)
        camera = build_camera(truth, sim_cell=cell, state_file=derived.sim_state)
        for device in (tracker, robot, camera):
            devices.callback(device.close)
            device.open()
        camera.configure(camera_settings(config))
        progress(f"simulated devices open: tracker {state['tracker']['port']}, robot {truth.robot.backend} "  # type: ignore[union-attr]
                 f"{state['robot']['host']}:{state['robot']['port']}, camera in process")
        yield CalibrationRig(config=config, config_path=config_path, tracker=tracker, robot=robot, camera=camera,
                             operator=operator, options=options, progress=progress,
                             truth_errors=truth_error_function(truth), sim=True)


def write_before_calibration(truth: CellConfig, data: dict[str, Any], path: Path, seed: int) -> Path:
    """``path``: the TOML ``data`` of the truth config (as read) with its calibration values perturbed (seeded
    with ``seed``), the taught flange poses of the measuring poses, the nominals the wizard needs and ``[sim]``
    cut down to what the simulated devices need to be found (the seed, the state file)."""
    assert truth.sim is not None and truth.reference.T_cf_b is not None
    rng = np.random.default_rng([seed, 0x504552])  # "PER"
    data = tomllib.loads(dumps_toml(data))  # a deep copy
    intr = data["camera"]["intrinsics"]
    scale = 1.0 + rng.uniform(-FOCAL_REL, FOCAL_REL)
    intr["fx"], intr["fy"] = float(intr["fx"]) * scale, float(intr["fy"]) * scale
    intr["cx"] = float(intr["cx"]) + rng.uniform(-PRINCIPAL_PX, PRINCIPAL_PX)
    intr["cy"] = float(intr["cy"]) + rng.uniform(-PRINCIPAL_PX, PRINCIPAL_PX)
    for k in ("k1", "k2", "p1", "p2"):
        intr[k] = 0.0
    ref = data["reference"]
    ref["T_cf_b"] = _perturbed(truth.reference.T_cf_b, *POSE_PERTURBATION["T_cf_b"], rng)
    parts = data.get("parts")  # a cell of part types: each part's reference is perturbed (the first in its place)
    first_T_cf_w0 = _perturbed(truth.reference.T_cf_w0, *POSE_PERTURBATION["T_cf_w0"], rng)
    if parts:
        parts[0]["T_cf_w0"] = first_T_cf_w0
    else:
        ref["T_cf_w0"] = first_T_cf_w0
    data["camera"]["T_f_c"] = _perturbed(truth.sim.T_f_c, *POSE_PERTURBATION["T_f_c"], rng)
    for entry, pose in zip(data["measuring_poses"], truth.cell_poses, strict=True):
        # the robot program's taught flange pose is known (read off the robot); where the camera then is, is not
        entry["T_b_f"] = (pose.T_b_f if pose.T_b_f is not None else compose(
            invert(truth.reference.T_cf_b), pose.T_cf_si, invert(truth.sim.T_f_c))).tolist()
        entry["T_cf_si"] = _perturbed(pose.T_cf_si, *POSE_PERTURBATION["T_cf_si"], rng)
    for entry, part in zip((parts or [])[1:], truth.parts[1:], strict=True):
        entry["T_cf_w0"] = _perturbed(part.T_cf_w0, *POSE_PERTURBATION["T_cf_w0"], rng)
    marks_rng = np.random.default_rng([seed, 0x4D524B])  # "MRK": its own stream, the draws above unchanged
    for entry, mark in zip(data.get("reference_marks") or [], truth.reference_marks, strict=True):
        shift = marks_rng.normal(size=3)
        entry["position_cf"] = (mark.position_cf + MARK_PERTURBATION_MM * shift / np.linalg.norm(shift)).tolist()
    if "cell_frame" not in data:
        data["cell_frame"] = {"method": "best-fit",
                              "benchmarks": {k: [float(v) for v in p] for k, p in truth.sim.benchmarks.items()}}
    if "calibration_target" not in data and truth.sim.targets:
        marks = default_target_marks()  # the simulated targets' marks (drivers/sim/cell.py SimCell.target_marks)
        origin = marks.centers_t[0]
        data["calibration_target"] = {
            "nests_t": np.asarray(truth.sim.targets[0].points_t, dtype=float).tolist(), "marks_cols": 13,
            "marks_rows": 9, "marks_pitch_mm": 20.0, "marks_radius_mm": float(marks.radius_mm),
            "marks_origin_t": [float(v) for v in origin]}
    data["sim"] = {k: data["sim"][k] for k in ("seed", "state_file") if k in data["sim"]}
    path.write_text(f"# The cell BEFORE calibration: written by `monoguide calibrate --sim` (seed {seed}) from the "
                    f"simulated cell\n# {truth.path}; its calibration values perturbed, its truth left out.\n"
                    + dumps_toml(data))
    return path


# --- private ------------------------------------------------------------------------------------


def _check_truth(truth: CellConfig) -> None:
    sim, r, t = truth.sim, truth.robot, truth.tracker
    problems = []
    if sim is None:
        problems.append("no [sim] section")
    else:
        if sim.tool_smr_f is None:
            problems.append("no [sim] tool_smr_f (the SMR on the flange tool)")
        if len(sim.targets) < len(truth.measuring_poses):
            problems.append(f"{len(sim.targets)} [[sim.targets]] for {len(truth.measuring_poses)} measuring poses")
        if len(sim.benchmarks) < 3:
            problems.append("fewer than 3 [sim.benchmarks]")
    if r is None or not r.simulated:
        problems.append("[robot] backend is not sim-ur or sim-kuka")
    if t is None or t.backend != "sim":
        problems.append("[tracker] backend is not sim")
    if truth.camera.backend != "sim":
        problems.append("[camera] backend is not sim")
    if truth.reference.T_cf_b is None:
        problems.append("no [reference] T_cf_b")
    if problems:
        raise SimRigConfigError(f"{truth.path}: not a simulated cell to calibrate: {'; '.join(problems)}")


def _perturbed(T: np.ndarray, mm: float, deg: float, rng: np.random.Generator) -> list[list[float]]:
    """``T`` moved by exactly ``mm`` and turned by exactly ``deg`` about its own origin, in seeded directions."""
    axis, shift = rng.normal(size=3), rng.normal(size=3)
    dT = make_T(rotvec_to_matrix(math.radians(deg) * axis / np.linalg.norm(axis)), np.zeros(3))
    moved = compose(np.asarray(T, dtype=float), dT)
    moved[:3, 3] += mm * shift / np.linalg.norm(shift)
    return moved.tolist()
