"""``monoguide calibrate --sim``: the calibration wizard's rig on the simulated cell, over the real transports.

:func:`open_sim_rig` makes a cell "before calibration" and everything the wizard needs to calibrate it:

- ``work_dir/cell.toml``: the truth config with its calibration values perturbed (seeded; intrinsics f ±1.5 %,
  cx cy ±20 px, no distortion; ``T_cf_b`` and ``T_cf_w0`` 5 mm / 0.3°, each ``T_cf_si`` 3 mm / 0.3°, ``T_f_c``
  2 mm / 0.2°), the measuring poses' taught flange poses ``T_b_f`` as the robot program has them, the
  ``[cell_frame]`` and ``[calibration_target]`` nominals, and a ``[sim]`` section stripped of the truth. That
  file is what the wizard calibrates; the truth stays in the truth config.
- ``monoguide sim-cell --no-plc`` for the truth config (on loopback ``host``, its state file and log in
  ``work_dir``) as a child process that dies with the wizard: the simulated tracker behind its pty and the
  simulated robot controller (UR or KUKA, as ``[robot] backend`` says) with its base-calibration poses.
- the tracker and the robot adapters (``daemon.assembly``, from sim-cell's state file), the simulated camera
  in this process following sim-cell's robot, and the simulated operator acting on the scene the camera
  renders and the tracker measures (``drivers/sim/calibration_scene.py``).
- ``truth_errors(step, result)``: each step's result against the truth config (section E of the wizard's
  interfaces; mm and deg from :func:`monoguide.solver.frames.pose_difference`).
"""

from __future__ import annotations

import contextlib
import math
import os
import signal
import subprocess
import sys
import threading
import time
import tomllib
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any

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
from monoguide.daemon.calibrate._rig import CalibrationOptions, CalibrationRig
from monoguide.daemon.config import CellConfig, load_cell_config
from monoguide.daemon.errors import SimRigConfigError, SimRigError
from monoguide.daemon.simulate import derive_config, dies_with_us, dumps_toml
from monoguide.solver.calibration.target import default_target_marks
from monoguide.solver.frames import compose, invert, make_T, pose_difference, rotvec_to_matrix

CELL_START_TIMEOUT_S = 90.0  # building the cell and starting its device processes on a busy machine
STOP_TIMEOUT_S = 10.0
FOCAL_REL = 0.015  # the perturbation of the calibration values: what "before calibration" means here
PRINCIPAL_PX = 20.0
POSE_PERTURBATION = {"T_cf_b": (5.0, 0.3), "T_cf_w0": (5.0, 0.3), "T_cf_si": (3.0, 0.3), "T_f_c": (2.0, 0.2)}


def _quiet(_text: str) -> None:
    return None


@contextmanager
def open_sim_rig(truth_config: Path, work_dir: Path, options: CalibrationOptions, *, seed: int = 1,
                 host: str | None = None, progress: Callable[[str], None] = _quiet) -> Iterator[CalibrationRig]:
    """The rig of ``monoguide calibrate --sim`` (see the module's doc); every device closed and the simulated
    cell stopped on leaving, however it is left."""
    work_dir = Path(work_dir).resolve()
    work_dir.mkdir(parents=True, exist_ok=True)
    derived = derive_config(Path(truth_config), work_dir / "sim-cell", host=host)
    truth = load_cell_config(derived.config)
    _check_truth(truth)
    config_path = write_before_calibration(truth, derived.data, work_dir / "cell.toml", seed)
    config = load_cell_config(config_path)
    progress(f"the cell before calibration: {config_path} (truth: {Path(truth_config).resolve()})")
    progress(f"starting the simulated cell on {derived.host} (log {work_dir / 'sim-cell.log'})")
    child = _SimCellProcess(derived.config, work_dir / "sim-cell.log")
    try:
        with contextlib.ExitStack() as devices:
            child.wait_listening()
            state = read_sim_state(derived.sim_state)
            cell = build_sim_cell(truth)
            operator = build_sim_operator(cell, Path(state["tracker"]["targets"]), Path(state["robot"]["truth"]),
                                          seed)
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
    finally:
        child.stop()


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
    ref["T_cf_w0"] = _perturbed(truth.reference.T_cf_w0, *POSE_PERTURBATION["T_cf_w0"], rng)
    data["camera"]["T_f_c"] = _perturbed(truth.sim.T_f_c, *POSE_PERTURBATION["T_f_c"], rng)
    for entry, pose in zip(data["measuring_poses"], truth.measuring_poses, strict=True):
        # the robot program's taught flange pose is known (read off the robot); where the camera then is, is not
        entry["T_b_f"] = (pose.T_b_f if pose.T_b_f is not None else compose(
            invert(truth.reference.T_cf_b), pose.T_cf_si, invert(truth.sim.T_f_c))).tolist()
        entry["T_cf_si"] = _perturbed(pose.T_cf_si, *POSE_PERTURBATION["T_cf_si"], rng)
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


def truth_error_function(truth: CellConfig) -> Callable[..., dict[str, float]]:
    """``truth_errors(step, result, earlier)``: how far each step's result is from the simulated truth.

    The frames measured with the tracker (base, part, SFi, ``T_s1_w0``) are compared in the cell frame as the
    ``cell`` step of ``earlier`` calibrated it: an error of the cell frame itself moves all of them alike and
    cancels in the offset (only ``T_b_s1``, ``T_s1_si`` and ``T_s1_w0`` reach it), so it is reported once, as
    ``cell_mm`` / ``cell_deg``, and the same figures in the true cell frame as ``*_true_cf``."""
    sim = truth.sim
    assert sim is not None and truth.reference.T_cf_b is not None
    T_cf_b, T_cf_w0, cam = truth.reference.T_cf_b, truth.reference.T_cf_w0, truth.camera.intrinsics
    T_cf_si = {p.name: p.T_cf_si for p in truth.measuring_poses}

    def truth_errors(step: str, result: dict[str, Any], earlier: dict[str, dict[str, Any]] | None = None
                     ) -> dict[str, float]:
        cell = (earlier or {}).get("cell") or {}
        # the true frames in the calibrated cell frame: T_cf'_x = T_cf'_tracker · T_tracker_cf · T_cf_x
        C = (np.asarray(cell["T_cf_tracker"], dtype=float) @ invert(sim.T_cf_tracker)
             if "T_cf_tracker" in cell else np.eye(4))
        out: dict[str, float] = {}

        def frame(name: str, T_est: Any, T_true: np.ndarray) -> None:
            out[f"{name}_deg"], out[f"{name}_mm"] = pose_difference(np.asarray(T_est, dtype=float), C @ T_true)
            if "T_cf_tracker" in cell:
                deg, mm = pose_difference(np.asarray(T_est, dtype=float), T_true)
                out[f"{name}_deg_true_cf"], out[f"{name}_mm_true_cf"] = deg, mm

        if step == "intrinsics" and "camera" in result:
            c = result["camera"]
            out["focal_rel_error"] = max(abs(float(c["fx"]) / cam.fx - 1.0), abs(float(c["fy"]) / cam.fy - 1.0))
        elif step == "cell" and "T_cf_tracker" in result:
            out["cell_deg"], out["cell_mm"] = pose_difference(np.asarray(result["T_cf_tracker"], dtype=float),
                                                              sim.T_cf_tracker)
        elif step == "base":
            if "T_cf_b" in result:
                frame("base", result["T_cf_b"], T_cf_b)
            if "smr_f" in result and sim.tool_smr_f is not None:
                out["smr_mm"] = float(np.linalg.norm(np.asarray(result["smr_f"], dtype=float) - sim.tool_smr_f))
        elif step == "part" and "T_cf_w0" in result:
            frame("part", result["T_cf_w0"], T_cf_w0)
        elif step == "sfi":
            errors = [(pose_difference(np.asarray(p["T_cf_si"], dtype=float), C @ T_cf_si[p["name"]]),
                       pose_difference(np.asarray(p["T_cf_si"], dtype=float), T_cf_si[p["name"]]))
                      for p in result.get("poses", []) if p.get("name") in T_cf_si]
            if errors:
                out["sfi_deg_max"] = max(e[0][0] for e in errors)
                out["sfi_mm_max"] = max(e[0][1] for e in errors)
                if "T_cf_tracker" in cell:
                    out["sfi_deg_max_true_cf"] = max(e[1][0] for e in errors)
                    out["sfi_mm_max_true_cf"] = max(e[1][1] for e in errors)
            if "T_f_c" in result:  # the camera on the flange: no cell frame in it
                out["hand_eye_deg"], out["hand_eye_mm"] = pose_difference(np.asarray(result["T_f_c"], dtype=float),
                                                                           sim.T_f_c)
        elif step == "verify" and truth.measuring_poses and "T_s1_w0" in result:  # relative: no cell frame in it
            T_s1_w0 = compose(invert(truth.measuring_poses[0].T_cf_si), T_cf_w0)
            out["s1_w0_deg"], out["s1_w0_mm"] = pose_difference(np.asarray(result["T_s1_w0"], dtype=float), T_s1_w0)
        return out

    return truth_errors


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


class _SimCellProcess:
    """``monoguide sim-cell --no-plc`` as a child in its own session (a Ctrl-C reaches the wizard, which stops
    it), dying with this process; its standard output read by a thread (the pipe never fills)."""

    def __init__(self, config: Path, log: Path) -> None:
        self.log = log
        self._log_file: IO[str] = log.open("w")
        argv = [sys.executable, "-m", "monoguide.daemon.cli", "sim-cell", "--config", str(config), "--no-plc"]
        # ends when this process ends, even by kill -9 (PR_SET_PDEATHSIG: Linux sends it when the *thread* that
        # started the child ends; open_sim_rig starts and stops sim-cell in the same call)
        self.process = subprocess.Popen(dies_with_us(argv),
                                        stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=self._log_file,
                                        text=True, start_new_session=True)
        self.lines: list[str] = []
        self._listening = threading.Event()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.process.stdout is not None
        with contextlib.suppress(ValueError, OSError):
            for line in self.process.stdout:
                self.lines.append(line.rstrip("\n"))
                if line.startswith("state file "):
                    self._listening.set()

    def wait_listening(self, timeout_s: float = CELL_START_TIMEOUT_S) -> None:
        """Until sim-cell says ``state file ...`` (it does once every device listens)."""
        deadline = time.monotonic() + timeout_s
        while not self._listening.wait(0.1):
            if self.process.poll() is not None:
                raise SimRigError(f"the simulated cell ended (status {self.process.returncode}) before its devices "
                                  f"listened; {self.log}: {self.tail()}")
            if time.monotonic() > deadline:
                raise SimRigError(f"the simulated cell did not say its devices listen within {timeout_s:g} s; its "
                                  f"output: {' | '.join(self.lines[-5:]) or '(none)'}; {self.log}: {self.tail()}")

    def tail(self, lines: int = 6) -> str:
        self._log_file.flush()
        try:
            text = self.log.read_text(errors="replace").strip().splitlines()
        except OSError:
            return "(no log)"
        return " | ".join(text[-lines:]) or "(its log is empty)"

    def stop(self) -> None:
        process = self.process
        if process.poll() is None:
            process.send_signal(signal.SIGTERM)
            try:
                process.wait(timeout=STOP_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait(timeout=STOP_TIMEOUT_S)
        with contextlib.suppress(OSError):  # whatever it left behind in its own session
            os.killpg(process.pid, signal.SIGKILL)
        if process.stdout is not None:
            with contextlib.suppress(OSError):
                process.stdout.close()
        self._log_file.close()
