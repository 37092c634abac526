"""`monoguide calibrate`: the session file, resume, bad options, and steps 1-3 against simulated devices.

The rig here is built from the simulated parts: the simulated tracker process over its pty with the real
``SerialLaserTracker`` (its flange SMR follows a robot truth file), a camera that renders the circle plate
(``target_renderer``) at seeded poses, and a robot that stops at seeded base-calibration poses with the cell's
repeatability and writes where it truly stands for the tracker. Every result is checked against the seeded
truth (the sim config's ``[sim]`` values), never against the wizard's own numbers.
"""

from __future__ import annotations

import json
import select
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from typer.testing import CliRunner

from monoguide.daemon.calibrate import (
    ACTIONS,
    MOUNT_FLANGE_SMR,
    PLACE_SMR,
    SESSION_FILE,
    SHOW_PLATE,
    CalibrationOptions,
    CalibrationRig,
    CalibrationSession,
    ConsoleOperator,
    open_session,
    plan_steps,
)
from monoguide.daemon.cli import app
from monoguide.daemon.cli._policy import EXIT_FAILED as EXIT_REFUSED
from monoguide.daemon.cli._policy import EXIT_INTERRUPTED, EXIT_OK
from monoguide.daemon.cli.calibrate import run_steps
from monoguide.daemon.config import CellConfig, CellFrameConfig, load_cell_config
from monoguide.daemon.errors import CalibrationAborted, CalibrationSessionInvalid
from monoguide.drivers.camera import CameraIdentity, CameraSettings, Frame
from monoguide.drivers.robot import RobotIdentity, RobotStatus
from monoguide.drivers.sim.cell import TARGETS_FORMAT
from monoguide.drivers.sim.target_renderer import base_calibration_poses, plate_camera_poses, render_target
from monoguide.drivers.tracker import SerialLaserTracker
from monoguide.solver.calibration.intrinsics import CirclePlate
from monoguide.solver.camera import CameraModel
from monoguide.solver.frames import compose, invert, pose_difference, pose_from_vector, transform_points

SIM_CELL = Path(__file__).parents[3] / "config" / "sim-cell.toml"
SEED = 11
# a collinear set and a set with one nest 1 mm off its nominal, beside the sim cell's B1..B3 (CF, mm)
COLLINEAR = {"L1": [0.0, 0.0, 0.0], "L2": [800.0, 0.0, 0.0], "L3": [1600.0, 0.0, 0.0]}
OFF_NEST = {"D4": ([900.0, 700.0, 100.0], [900.0, 700.0, 101.0])}  # nominal, true (1 mm higher)


# --- the simulated parts ------------------------------------------------------------------------


@dataclass
class Truth:
    config: CellConfig
    T_cf_tracker: np.ndarray
    T_cf_b: np.ndarray
    smr_f: np.ndarray
    camera: CameraModel


@pytest.fixture(scope="module")
def truth() -> Truth:
    cfg = load_cell_config(SIM_CELL)
    assert cfg.sim is not None and cfg.sim.tool_smr_f is not None
    # a half-size camera keeps the rendering fast; its model is the truth the intrinsics are checked against
    c = cfg.camera.intrinsics
    small = replace(c, width=c.width // 2, height=c.height // 2, fx=c.fx / 2, fy=c.fy / 2, cx=c.cx / 2, cy=c.cy / 2)
    return Truth(cfg, cfg.sim.T_cf_tracker, cfg.reference.T_cf_b, np.asarray(cfg.sim.tool_smr_f, float), small)


@dataclass
class SimTrackerProcess:
    port: str
    targets: Path
    robot_truth: Path


@pytest.fixture(scope="module")
def sim_tracker(truth: Truth, tmp_path_factory: pytest.TempPathFactory) -> Iterator[SimTrackerProcess]:
    """The simulated tracker process: the benchmark nests (B1..B3, the collinear L1..L3, D4 1 mm off its
    nominal) in the tracker's frame, and the flange SMR "TCP" wherever the robot truth file says the flange is."""
    work = tmp_path_factory.mktemp("tracker")
    robot_truth = work / "robot-truth.json"
    robot_truth.write_text(json.dumps({"T_b_f": np.eye(4).tolist()}))
    T_tracker_cf = invert(truth.T_cf_tracker)
    nests_cf = {**{k: np.asarray(v) for k, v in truth.config.sim.benchmarks.items()},
                **{k: np.asarray(v) for k, v in COLLINEAR.items()}, "D4": np.asarray(OFF_NEST["D4"][1])}
    nests = {k: transform_points(T_tracker_cf, v.reshape(1, 3))[0].tolist() for k, v in nests_cf.items()}
    targets = work / "targets.json"
    targets.write_text(json.dumps({
        "format": TARGETS_FORMAT, "noise_mm": truth.config.sim.tracker_noise_mm, "beam_on": "B1", "nests": nests,
        "flange": {"nest": "TCP", "truth": str(robot_truth), "smr_f": truth.smr_f.tolist(),
                   "T_tracker_b": compose(T_tracker_cf, truth.T_cf_b).tolist()}}))
    process = subprocess.Popen([sys.executable, "-m", "monoguide.drivers.sim.tracker", "--targets", str(targets),
                                "--seed", str(SEED)], stdout=subprocess.PIPE, text=True)
    assert process.stdout is not None
    ready, _, _ = select.select([process.stdout], [], [], 15.0)
    words = process.stdout.readline().split() if ready else []
    try:
        assert words[:2] == ["LISTEN", "tracker"], f"simulated tracker did not start: {words}"
        yield SimTrackerProcess(words[2], targets, robot_truth)
    finally:
        process.terminate()
        process.wait(5)
        process.stdout.close()


class PlateCamera:
    """A simulated camera that images the circle plate where the operator holds it (seeded poses)."""

    def __init__(self, model: CameraModel, n: int, seed: int) -> None:
        self.model, self.plate = model, CirclePlate()
        self.rng = np.random.default_rng(seed)
        self.poses = plate_camera_poses(self.plate.centre(), 650.0, n, self.rng)
        self.k: int | None = None
        self.frames = 0

    @property
    def identity(self) -> CameraIdentity:
        return CameraIdentity("sim", "plate camera", "PC-1")

    def open(self) -> CameraIdentity:
        return self.identity

    def configure(self, settings: CameraSettings) -> None:
        pass

    def grab(self, timeout_s: float) -> Frame:
        assert self.k is not None, "grab without the plate in view"
        image = render_target(self.model, self.poses[self.k], self.plate.points(), self.plate.radius_mm, self.rng).image
        self.frames += 1
        return Frame(image, self.frames, time.time())

    def close(self) -> None:
        pass


class CalibrationPoseRobot:
    """A robot at seeded base-calibration poses: it stops with the cell's repeatability, reports where it stands
    and writes that into the robot truth file the simulated tracker's flange SMR follows."""

    def __init__(self, truth_file: Path, n: int, seed: int, repeatability_mm: float, repeatability_deg: float
                 ) -> None:
        self.rng = np.random.default_rng(seed)
        self.taught = base_calibration_poses(n, self.rng)
        self.truth_file, self.mm, self.deg = truth_file, repeatability_mm, repeatability_deg
        self.visited: list[int] = []

    @property
    def identity(self) -> RobotIdentity:
        return RobotIdentity("sim", "calibration robot", "CR-1", "1", "in process")

    def move_to_calibration_pose(self, k: int, timeout_s: float | None = None) -> RobotStatus:
        noise = np.concatenate([np.radians(self.rng.normal(0.0, self.deg, 3)), self.rng.normal(0.0, self.mm, 3)])
        T_b_f = compose(self.taught[k - 1], pose_from_vector(noise))
        tmp = self.truth_file.with_name("robot-truth.tmp")
        tmp.write_text(json.dumps({"T_b_f": T_b_f.tolist()}))
        tmp.replace(self.truth_file)
        self.visited.append(k)
        return RobotStatus(T_b_f, "RUNNING", "NORMAL", True, 100 + k, k, 0)


@dataclass
class ScriptOperator:
    """Does what it is asked on the simulated cell (holds the plate up) and remembers every request."""

    camera: PlateCamera
    asked: list[tuple[str, dict[str, Any]]] = field(default_factory=list)
    interrupt_at: str | None = None

    def ask(self, action: str, instruction: str, **detail: Any) -> None:
        assert action in ACTIONS and instruction
        self.asked.append((action, detail))
        if action == self.interrupt_at:
            raise KeyboardInterrupt
        if action == SHOW_PLATE:
            self.camera.k = detail["k"]


@pytest.fixture
def make_rig(truth: Truth, sim_tracker: SimTrackerProcess) -> Iterator[Any]:
    trackers: list[SerialLaserTracker] = []

    def make(options: CalibrationOptions, config: CellConfig | None = None, seed: int = SEED) -> CalibrationRig:
        while trackers:  # one client at a time holds the tracker's port
            trackers.pop().close()
        tracker = SerialLaserTracker(sim_tracker.port, timeout_s=3.0)
        tracker.open()
        trackers.append(tracker)
        sim = truth.config.sim
        camera = PlateCamera(truth.camera, options.plate_images, seed)
        robot = CalibrationPoseRobot(sim_tracker.robot_truth, options.base_poses, seed, sim.repeatability_mm,
                                     sim.repeatability_deg)
        return CalibrationRig(config or truth.config, SIM_CELL, tracker, robot, camera,  # type: ignore[arg-type]
                              ScriptOperator(camera), options, lambda line: None)

    yield make
    for tracker in trackers:
        tracker.close()


def _session(tmp_path: Path, **options: Any) -> tuple[CalibrationSession, CalibrationOptions]:
    return open_session(tmp_path, SIM_CELL, False, options)


# --- steps 1-3 against the simulated devices ------------------------------------------------------


def test_intrinsics_cell_and_base_meet_the_seeded_truth(make_rig: Any, truth: Truth, tmp_path: Path) -> None:
    session, options = _session(tmp_path, plate_images=7, base_poses=8)
    rig = make_rig(options)
    lines: list[str] = []
    assert run_steps(rig, session, ["intrinsics", "cell", "base"], human=lines.append) == EXIT_OK
    saved = CalibrationSession.load(tmp_path / SESSION_FILE)
    assert saved is not None and saved.done() == ["intrinsics", "cell", "base"]
    steps = saved.data["steps"]
    cam = steps["intrinsics"]["camera"]
    assert abs(cam["fx"] / truth.camera.fx - 1) < 2e-3 and abs(cam["fy"] / truth.camera.fy - 1) < 2e-3
    assert abs(cam["cx"] - truth.camera.cx) < 3.0 and abs(cam["cy"] - truth.camera.cy) < 3.0
    assert steps["intrinsics"]["images"] == 7 and len(steps["intrinsics"]["per_image_rms_px"]) == 7
    deg, mm = pose_difference(np.array(steps["cell"]["T_cf_tracker"]), truth.T_cf_tracker)
    assert mm < 0.1 and deg < 0.01, (mm, deg)
    assert set(steps["cell"]["residuals_mm"]) == {"B1", "B2", "B3"}
    deg, mm = pose_difference(np.array(steps["base"]["T_cf_b"]), truth.T_cf_b)
    assert mm < 0.3 and deg < 0.02, (mm, deg)
    assert np.linalg.norm(np.array(steps["base"]["smr_f"]) - truth.smr_f) < 0.3
    assert len(steps["base"]["flange_poses"]) == 8 and rig.robot.visited == list(range(1, 9))
    asked = [a for a, _ in rig.operator.asked]
    assert asked.count(SHOW_PLATE) == 7 and asked.count(PLACE_SMR) == 3 and MOUNT_FLANGE_SMR in asked
    assert [d["nest"] for a, d in rig.operator.asked if a == PLACE_SMR] == ["B1", "B2", "B3"]
    assert any(line.startswith("robot base: RMS") for line in lines)


def test_cell_frame_three_two_one(make_rig: Any, truth: Truth, tmp_path: Path) -> None:
    session, options = _session(tmp_path, cell_method="3-2-1")
    assert run_steps(make_rig(options), session, ["cell"], human=lambda _: None) == EXIT_OK
    result = session.data["steps"]["cell"]
    deg, mm = pose_difference(np.array(result["T_cf_tracker"]), truth.T_cf_tracker)
    # 3-2-1 puts all of B1's noise into the origin and B2's into the x axis: looser than the best fit
    assert result["method"] == "3-2-1" and mm < 0.1 and deg < 0.01, (mm, deg)


# --- refusals --------------------------------------------------------------------------------------


def _with_benchmarks(truth: Truth, benchmarks: dict[str, list[float]]) -> CellConfig:
    return replace(truth.config, cell_frame=CellFrameConfig("best-fit", {k: np.asarray(v, float)
                                                                          for k, v in benchmarks.items()}))


@pytest.mark.parametrize(("benchmarks", "code", "words"), [
    (COLLINEAR, "CALIBRATION_DEGENERATE", "L1, L2, L3 are (nearly) collinear"),
    ({"B1": [0.0, 0.0, 0.0], "B2": [1500.0, 0.0, 0.0], "B3": [0.0, 1200.0, 0.0], "D4": OFF_NEST["D4"][0]},
     "CALIBRATION_RESIDUAL_TOO_LARGE", "point D4 is"),
], ids=["collinear", "residual"])
def test_cell_frame_refusals(make_rig: Any, truth: Truth, tmp_path: Path, capsys: pytest.CaptureFixture[str],
                             benchmarks: dict[str, Any], code: str, words: str) -> None:
    session, options = _session(tmp_path)
    rig = make_rig(options, _with_benchmarks(truth, benchmarks))
    assert run_steps(rig, session, ["cell"]) == EXIT_REFUSED
    refused = CalibrationSession.load(tmp_path / SESSION_FILE).data["refused"]["cell"]
    assert refused["code"] == code and words in refused["message"] and refused["plc_code"] in (701, 703)
    assert f"{code} step 'cell' refused: " in capsys.readouterr().err


def test_too_few_base_poses_refused_then_resumed_at_base(make_rig: Any, truth: Truth, tmp_path: Path) -> None:
    """A refusal stops the run; the next run (more poses) resumes at the refused step, the cell not redone."""
    session, options = _session(tmp_path, base_poses=4)
    assert run_steps(make_rig(options), session, ["cell", "base"]) == EXIT_REFUSED
    first = CalibrationSession.load(tmp_path / SESSION_FILE)
    assert first.done() == ["cell"] and first.data["refused"]["base"]["code"] == "CALIBRATION_TOO_FEW_VIEWS"
    cell_done = first.data["steps"]["cell"]["done"]

    session, options = _session(tmp_path, base_poses=8, plate_images=6)
    assert options.base_poses == 8
    to_run = plan_steps(session, None, None)
    assert to_run[:2] == ["intrinsics", "base"]
    rig = make_rig(options)
    assert run_steps(rig, session, ["base"]) == EXIT_OK
    again = CalibrationSession.load(tmp_path / SESSION_FILE)
    assert again.done() == ["cell", "base"] and again.data["steps"]["cell"]["done"] == cell_done
    assert "base" not in again.data["refused"]
    assert not [a for a, _ in rig.operator.asked if a == PLACE_SMR]  # the benchmarks were not measured again


def test_interrupt_mid_run_then_resume(make_rig: Any, tmp_path: Path) -> None:
    session, options = _session(tmp_path, base_poses=8)
    rig = make_rig(options)
    rig.operator.interrupt_at = MOUNT_FLANGE_SMR
    with pytest.raises(KeyboardInterrupt):
        run_steps(rig, session, ["cell", "base"])
    assert CalibrationSession.load(tmp_path / SESSION_FILE).done() == ["cell"]
    session, options = _session(tmp_path)
    assert options.base_poses == 8  # the session's options, not the defaults
    rig = make_rig(options)
    assert run_steps(rig, session, ["base"]) == EXIT_OK
    assert CalibrationSession.load(tmp_path / SESSION_FILE).done() == ["cell", "base"]


def test_end_of_input_at_a_prompt_aborts(make_rig: Any, tmp_path: Path) -> None:
    session, options = _session(tmp_path)
    rig = make_rig(options)

    with (tmp_path / "prompts.txt").open("w") as stream:
        rig.operator = ConsoleOperator(yes=False, stream=stream, read=_eof)
        assert run_steps(rig, session, ["cell"]) == EXIT_INTERRUPTED
    assert "place the SMR in benchmark nest B1, press Enter" in (tmp_path / "prompts.txt").read_text()
    assert CalibrationSession.load(tmp_path / SESSION_FILE).done() == []


# --- the session file --------------------------------------------------------------------------------


def test_session_round_trip_and_option_rules(tmp_path: Path) -> None:
    session, options = _session(tmp_path, plate_images=8, visits=2)
    assert (options.plate_images, options.visits, options.placements) == (8, 2, 10)
    result = {"T_cf_tracker": np.eye(4).tolist(), "residuals_mm": {"B1": 0.01}, "rms_mm": 0.01, "method": "best-fit"}
    session.record_result("cell", result)
    session.record_result("intrinsics", {"camera": {"fx": 1.0}, "rms_px": 0.1})
    loaded = CalibrationSession.load(tmp_path / SESSION_FILE)
    assert loaded is not None and loaded.done() == ["intrinsics", "cell"] and loaded.next_step() == "base"
    assert {k: v for k, v in loaded.data["steps"]["cell"].items() if k != "done"} == result
    assert loaded.missing_for("verify") == ["base", "part", "sfi"]
    # an option that shaped a step done may not change; one for a later step may
    with pytest.raises(CalibrationSessionInvalid, match=r"--plate-images 12 \(step 'intrinsics' was done with 8\)"):
        _session(tmp_path, plate_images=12)
    _, options = _session(tmp_path, visits=3)
    assert options.visits == 3 and options.plate_images == 8
    with pytest.raises(CalibrationSessionInvalid, match="this session calibrates"):
        open_session(tmp_path, tmp_path / "other.toml", False, {})
    with pytest.raises(CalibrationSessionInvalid, match="made without --sim"):
        open_session(tmp_path, SIM_CELL, True, {})
    loaded = CalibrationSession.load(tmp_path / SESSION_FILE)
    loaded.record_result("base", {"T_cf_b": np.eye(4).tolist()})
    assert plan_steps(loaded, "cell", None) == ["cell"] and loaded.done() == ["intrinsics"]  # base needs cell
    loaded.record_result("cell", result)
    assert loaded.forget_from("cell") == ["cell"] and loaded.done() == ["intrinsics"]
    _, options = open_session(tmp_path, SIM_CELL, False, {}, restart=True)
    assert CalibrationSession.load(tmp_path / SESSION_FILE).done() == [] and options.plate_images == 12
    assert (tmp_path / (SESSION_FILE + ".previous")).exists()


# --- the command line ----------------------------------------------------------------------------------


def _invoke(*args: str) -> Any:
    return CliRunner().invoke(app, ["calibrate", *args])


@pytest.mark.parametrize(("args", "words"), [
    (["--plate-images", "0"], "--plate-images 0: must be positive"),
    (["--cell-method", "fit"], "--cell-method 'fit': expected one of best-fit, 3-2-1"),
    (["lens"], "STEP 'lens': not a step"),
    (["base"], "step 'base' needs cell done first"),
    (["--values", "VALUES"], "unknown option 'exposure'"),
])
def test_bad_options_exit_2(tmp_path: Path, args: list[str], words: str) -> None:
    (tmp_path / "values.toml").write_text("plate-images = 8\nexposure = 3\n")
    args = [str(tmp_path / "values.toml") if a == "VALUES" else a for a in args]
    result = _invoke(*args, "--config", str(SIM_CELL), "--work-dir", str(tmp_path))
    assert result.exit_code == 2 and words in result.stderr, result.output


def test_without_config_exit_2() -> None:
    result = _invoke("--yes")
    assert result.exit_code == 2 and "--config CELL.toml is required" in result.stderr


def test_corrupt_session_is_named_and_kept(tmp_path: Path) -> None:
    path = tmp_path / SESSION_FILE
    path.write_text('{"format": "monoguide.calibration-session/1", "steps": {')
    result = _invoke("--config", str(SIM_CELL), "--work-dir", str(tmp_path), "--yes", "--json")
    assert result.exit_code == 2 and f"{path}: the calibration session is corrupt" in result.stderr
    assert path.read_text() == '{"format": "monoguide.calibration-session/1", "steps": {'


def test_console_operator_prompts(tmp_path: Path) -> None:
    shown = tmp_path / "shown.txt"
    with shown.open("w") as stream:
        answers: list[str] = []
        ConsoleOperator(False, stream, read=lambda _: answers.append("") or "").ask(PLACE_SMR, "place it", nest="B2")
        ConsoleOperator(True, stream, read=lambda _: pytest.fail("--yes waited")).ask(SHOW_PLATE, "show", k=0, n=1)
        with pytest.raises(ValueError, match="unknown operator action"):
            ConsoleOperator(True, stream).ask("dance", "dance")
    assert answers == [""] and shown.read_text().splitlines() == ["> place it, press Enter", "> show"]
    with (tmp_path / "x").open("w") as stream, pytest.raises(CalibrationAborted, match="aborted at the prompt"):
        ConsoleOperator(False, stream, read=_eof).ask(PLACE_SMR, "x", nest="B1")


def _eof(_prompt: str) -> str:
    raise EOFError



# --- the whole wizard on the simulated cell ----------------------------------------------------------


def test_sim_wizard_cell_then_base_against_the_truth(tmp_path: Path) -> None:
    """``monoguide calibrate STEP --sim --yes --json`` twice (the simulated cell restarted in between): the
    session carries the cell frame into the base step; both are checked against the truth config. (The whole
    wizard with small counts takes minutes here: its SFi visits dominate; see the report.)"""
    work = tmp_path / "work"
    command = [sys.executable, "-m", "monoguide.daemon.cli", "calibrate", "--sim", "--yes", "--json",
               "--config", str(SIM_CELL), "--work-dir", str(work), "--host", "127.0.15.2", "--seed", "3"]
    first = subprocess.run([*command, "cell"], capture_output=True, text=True, timeout=120)
    assert first.returncode == 0, first.stderr[-3000:]
    run = subprocess.run([*command, "base", "--base-poses", "8"], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr[-3000:]
    summary = json.loads(run.stdout.strip().splitlines()[-1])
    assert summary["steps_done"] == ["cell", "base"] and summary["refused"] == {} and summary["sim"] is True
    assert summary["calibration_file"] is None  # not before every step is done
    truth = load_cell_config(SIM_CELL)
    steps = json.loads((work / SESSION_FILE).read_text())["steps"]
    deg, mm = pose_difference(np.array(steps["cell"]["T_cf_tracker"]), truth.sim.T_cf_tracker)
    assert mm < 0.3 and deg < 0.01, (mm, deg)
    deg, mm = pose_difference(np.array(steps["base"]["T_cf_b"]), truth.reference.T_cf_b)
    assert mm < 0.3 and deg < 0.02, (mm, deg)  # the cell before calibration had it 5 mm / 0.3 deg off
    assert summary["base_mm_true_cf"] == pytest.approx(mm, abs=1e-6)
    assert summary["base_deg_true_cf"] == pytest.approx(deg, abs=1e-6)
    # base_mm / base_deg: in the cell frame as calibrated (its own error moves every frame alike)
    C = np.array(steps["cell"]["T_cf_tracker"]) @ np.linalg.inv(truth.sim.T_cf_tracker)
    deg, mm = pose_difference(np.array(steps["base"]["T_cf_b"]), C @ truth.reference.T_cf_b)
    assert summary["base_mm"] == pytest.approx(mm, abs=1e-6) and summary["base_deg"] == pytest.approx(deg, abs=1e-6)
    assert np.linalg.norm(np.array(steps["base"]["smr_f"]) - truth.sim.tool_smr_f) < 0.3
    assert summary["focal_rel_error"] is None and summary["sfi_mm_max"] is None
