"""The work of one measuring cycle, blocking: measure, solve, check, write (docs/cycle.md).

:class:`CycleRunner` holds no asyncio and no PLC: the service (``daemon/service/``) calls its four steps in worker
threads and fires the state machine (``daemon/cycle/_states.py``) between them.

- :meth:`CycleRunner.measure` visits every measuring pose: request it, wait until the robot is in position (its
  status carries the actual flange pose, recorded with the capture; the robot adapter refuses a stop off the
  taught pose, ``ROBOT_POSE_MISMATCH``), grab, and find the hole(s) the pose expects in a region predicted from
  the reference part widened by the deviation envelope (:mod:`monoguide.solver.planning.search`). Finding the
  holes of view i runs in a worker thread while the robot moves to view i + 1. It returns the measurement
  record of ``docs/measurement-record.md``, built and parsed once.
- :meth:`CycleRunner.solve`: the pose (maximum likelihood), one perspective-correction iteration (the centre of
  an imaged hole is not the image of its centre), the checked solve, the base offset ``D_b`` in the robot base
  frame and the quality figures the PLC shows. With marks the checked solve is the joint fit of the part and of
  every view's camera pose (``solver/marks_check.py``, docs/cycle-marks.md): a camera that stood elsewhere than
  calibrated is refused with ``CALIBRATION_SUSPECT``, and each view's deviation goes into the result
  (``camera_deviation``).
- :meth:`CycleRunner.check`: the reprojection RMS, the predicted sigma, the offset envelope (``[checks]``).
- :meth:`CycleRunner.write`: the offset to the robot, acknowledged by its sequence number.

Timings (seconds) go into one dict, ``Measurement.timings_s``, shared with ``Solution.timings_s``:
``robot_motion``, ``exposure``, ``hole_finding`` (measure), ``solve``, ``checks``, ``offset_write`` and
``overhead`` (the last frame in hand -> the offset acknowledged) (write).
"""

from __future__ import annotations

import contextlib
import logging
import math
import threading
import time
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from monoguide.daemon.config import CellConfig, ChecksConfig
from monoguide.daemon.cycle._images import ImageWriter, image_path
from monoguide.daemon.cycle._marks import MARK_FINDERS, find_mark, plan_marks
from monoguide.daemon.cycle._record import Capture, Measurement, RecordBuilder, Solution
from monoguide.daemon.cycle._residual import Residual
from monoguide.daemon.cycle._seen import Sought, ViewsSeen, wait_images
from monoguide.drivers.camera import Camera, CameraSettings, Frame
from monoguide.drivers.errors import ConfigError, DeviceError
from monoguide.drivers.robot import Robot
from monoguide.solver import frames
from monoguide.solver.errors import (
    CalibrationSuspect,
    InconsistentMeasurement,
    MonoguideError,
    ResidualTooLarge,
    UncertaintyTooLarge,
)
from monoguide.solver.hole_edges import bit_depth_of
from monoguide.solver.holes import measure_hole
from monoguide.solver.marks_problem import MIN_MARKS_PER_VIEW
from monoguide.solver.offset import check_envelope
from monoguide.solver.planning import DeviationEnvelope
from monoguide.solver.planning.prediction import pose_sigmas
from monoguide.solver.planning.search import HoleSearch, hole_search, search_extremes
from monoguide.solver.pose import solve_ml, solve_pose
from monoguide.solver.problem import PoseProblem
from monoguide.solver.record import result_to_dict
from monoguide.solver.record_marks import camera_deviation, solve_record_marks
from monoguide.solver.trend import residual_chi2, view_statistics

log = logging.getLogger(__name__)

@dataclass(frozen=True)
class _View:
    """Where the holes of one measuring pose are sought (pose.points order)."""

    points: tuple[int, ...]
    holes: tuple[HoleSearch, ...]
    marks: tuple[int, ...] = ()  # the [[reference_marks]] it sees
    mark_searches: tuple[HoleSearch, ...] = ()
    mark_shifts: tuple[tuple[float, float], ...] = ()  # imaged circle's centre minus the image of the mark's centre


class CycleRunner:
    """The blocking steps of a cycle on opened devices; one runner serves every cycle on the same camera and
    robot (the service builds a new one when a device was reopened). Building it plans the views (~0.1 s, off
    the cycle's path); the camera is configured at the first :meth:`measure` and again after a failed grab.
    ``images_dir`` may be changed between cycles (the service gives each cycle its own folder).

    The runner owns two worker threads, kept for every cycle (not a new thread per cycle): one finds holes while
    the robot moves, one writes the PNGs off the cycle's path. :meth:`close` (or leaving ``with``) ends them."""

    def __init__(self, config: CellConfig, camera: Camera, robot: Robot, images_dir: Path | None = None) -> None:
        if config.reference.T_cf_b is None:
            raise ConfigError(f"{config.path}: [reference] T_cf_b: the cycle needs the robot base in the cell frame "
                              f"to give the offset in the robot's frame")
        self.config, self.camera, self.robot, self.images_dir = config, camera, robot, images_dir
        self.checks = config.checks or ChecksConfig()
        c = config.camera
        self.settings = CameraSettings(c.pixel_format, c.exposure_us, c.gain_db, c.region)
        self.records = RecordBuilder(config, self.checks, config.taught_flange_poses())
        self._views = tuple(self._plan_view(i) for i in range(len(config.measuring_poses)))
        self._camera_configured = False
        self._finder = ThreadPoolExecutor(1, thread_name_prefix="monoguide-holes")
        self._mark_finder = ThreadPoolExecutor(MARK_FINDERS, thread_name_prefix="monoguide-marks")
        self._images = ImageWriter()

    def close(self) -> None:
        """End the worker threads (a PNG still being written is finished first)."""
        self._finder.shutdown(wait=True, cancel_futures=True)
        self._mark_finder.shutdown(wait=True, cancel_futures=True)
        self._images.close()

    def __enter__(self) -> CycleRunner:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    # --- the four steps ---------------------------------------------------------------------------

    def measure(self, job: int, abort: threading.Event, abort_error: Callable[[], MonoguideError],
                holes: bool = True, seen: ViewsSeen | None = None) -> Measurement:
        """Visit every measuring pose; raise ``abort_error()`` when ``abort`` is set (checked before each
        request and after each wait). ``job`` has been checked by the caller (the service's job rule).
        ``holes`` False: the marks alone (the check job of a cell with marks; no part needed), its record has no
        hole observations and is not parsed (``Measurement.parsed`` None). ``seen`` is told each view as it is
        visited and what its finder found or where it failed (what a failed cycle is journaled with)."""
        seen = seen if seen is not None else ViewsSeen()
        timings = {"robot_motion": 0.0, "exposure": 0.0, "hole_finding": 0.0}
        with device_errors("camera"):
            self._configure_camera()
        poses = self.config.measuring_poses
        futures: list[Future[tuple[Capture, float]]] = []
        last_frame_at = 0.0
        images: list[Future[bool]] = []
        i = 0
        try:
            for i in range(len(poses)):
                _check_abort(abort, abort_error)
                if futures and futures[-1].done():
                    futures[-1].result()  # a view already failed: no need to visit the next one
                t0 = time.monotonic()
                with device_errors("robot"):
                    status = self.robot.move_to_measuring_pose(poses[i].number - 1)  # the cell's pose
                t1 = time.monotonic()
                _check_abort(abort, abort_error)
                with device_errors("camera"):
                    frame = self._grab()
                last_frame_at = time.monotonic()
                timings["robot_motion"] += t1 - t0
                timings["exposure"] += last_frame_at - t1
                path = image_path(self.images_dir, poses[i].name)
                writing = None if path is None else self._images.submit(path, frame.image, poses[i].name)
                if writing is not None:
                    images.append(writing)
                T_b_f = np.array(status.T_b_f, dtype=float)
                seen.visited(i, poses[i].name, None if path is None else str(path), T_b_f,
                             self._sought(i) if holes else (), writing)
                futures.append(self._finder.submit(self._find, i, frame, T_b_f, path, holes, seen))
            captures = []
            for i, future in enumerate(futures):  # noqa: B007 (i: the view waited for, if this wait fails)
                while True:  # every wait has a way out: the abort
                    _check_abort(abort, abort_error)
                    try:
                        capture, seconds = future.result(timeout=0.05)
                        break
                    except TimeoutError:
                        continue
                captures.append(capture)
                timings["hole_finding"] += seconds
        except BaseException:
            seen.failed(poses[i].name)  # where the robot, the camera or an abort stopped it (a finder's came first)
            raise
        finally:
            for future in futures:
                future.cancel()  # those not started; a running one ends on its own (it only reads its frame)
        if not holes:
            return self.records.marks_measurement(job, captures, timings, last_frame_at, images)
        return self.records.measurement(job, captures, timings, last_frame_at, images)

    @property
    def has_marks(self) -> bool:
        """Every measuring pose of this part type sees enough marks to measure its camera (the check job then
        needs no part)."""
        return all(len(view.marks) >= MIN_MARKS_PER_VIEW for view in self._views)

    def solve(self, measurement: Measurement) -> Solution:
        """Pose, covariance, one perspective-correction iteration; the measurement's record and captures are
        updated to the corrected centres (so that re-solving the journal's record gives this result:
        ``monoguide journal resolve N --config CELL.toml``, which weighs the views at the flange as here)."""
        start = time.monotonic()
        first = solve_ml(measurement.parsed.problem)  # unchecked: its centres are the ellipses', not yet corrected
        record = self.records.correct(measurement, first.T_s1_w)
        extra: dict[str, object] = {}
        residual: Residual | None = None
        try:
            if record.marks is None:
                result = solve_pose(record.problem, "ml", false_alarm_rate=self.checks.false_alarm_rate)
            else:  # the trend monitor's evidence stays the holes' own, as in a cell without marks
                holes = solve_ml(record.problem, first.T_s1_w).T_s1_w
                residual = _residual(record.problem, holes)
                result, fit = solve_record_marks(record.problem, record.marks,
                                                 false_alarm_rate=self.checks.marks_false_alarm_rate,
                                                 consistency_false_alarm_rate=self.checks.false_alarm_rate,
                                                 T_init=holes)
                extra["camera_deviation"] = camera_deviation(fit)
        except (InconsistentMeasurement, CalibrationSuspect) as exc:  # evidence for the trend monitor all the same
            exc.residual = residual or _residual(record.problem,  # type: ignore[attr-defined]
                                                 solve_ml(record.problem).T_s1_w)
            raise
        elapsed = time.monotonic() - start
        displacement = record.displacement(result.T_s1_w)
        assert displacement.base_offset is not None  # the record carries T_b_s1
        D_b = displacement.base_offset
        sigmas = pose_sigmas(result.covariance, result.T_s1_w, record.grasp_point_w)
        measurement.timings_s["solve"] = elapsed
        residual = residual or _residual(record.problem, result.T_s1_w)
        return Solution(
            result={**result_to_dict(record, result, elapsed * 1e3), **extra, "calibration_residual": {
                "chi2": residual.chi2, "dof": residual.dof, "per_view": [list(v) for v in residual.per_view]}},
            D_b=D_b,
            offset=frames.T_to_kuka_frame(D_b),
            quality=(result.rms_px, sigmas.sigma_trans_mm, sigmas.sigma_rot_deg),
            timings_s=measurement.timings_s,
            last_frame_at=measurement.last_frame_at,
            T_s1_w=result.T_s1_w,
            displacement=displacement,
            images=measurement.images,
            residual=residual,
        )

    def check(self, measurement: Measurement, solution: Solution) -> None:
        """Raise the first failing check's error: the RMS (``RESIDUAL_TOO_LARGE``), the predicted sigma
        (``UNCERTAINTY_TOO_LARGE``), the offset envelope (``OFFSET_OUT_OF_ENVELOPE``)."""
        start = time.monotonic()
        try:
            c = self.checks
            rms, sigma_mm, sigma_deg = solution.quality
            if not rms <= c.max_rms_px:
                raise ResidualTooLarge(f"reprojection RMS {rms:.3f} px above [checks] max_rms_px = {c.max_rms_px:g}")
            if not (sigma_mm <= c.max_sigma_mm and sigma_deg <= c.max_sigma_deg):
                raise UncertaintyTooLarge(
                    f"predicted sigma {sigma_mm:.3f} mm at the grasp point / {sigma_deg:.4f} deg above [checks] "
                    f"max_sigma_mm = {c.max_sigma_mm:g} / max_sigma_deg = {c.max_sigma_deg:g}")
            displacement = solution.displacement
            if displacement is None:  # a solution not of this runner's solve (tests build their own)
                T_s1_w = solution.T_s1_w if solution.T_s1_w is not None else np.array(solution.result["T_s1_w"])
                displacement = measurement.parsed.displacement(T_s1_w)
            check_envelope(displacement, measurement.parsed.envelope)
        finally:
            measurement.timings_s["checks"] = time.monotonic() - start

    def write(self, solution: Solution, before_send: Callable[[int], None] | None = None) -> int:
        """Write ``D_b`` to the robot; returns the sequence number it acknowledged. ``before_send(sequence)``
        runs before anything goes on the wire (the journal's intent): when it raises, nothing is sent."""
        start = time.monotonic()
        with device_errors("robot"):
            sequence = self.robot.write_base_offset(solution.D_b, before_send=before_send)
        done = time.monotonic()
        solution.timings_s["offset_write"] = done - start
        if solution.last_frame_at:
            solution.timings_s["overhead"] = done - solution.last_frame_at
        wait_images(solution.images)  # after the acknowledgment: the PNGs are not on the overhead path
        return sequence

    # --- measuring ----------------------------------------------------------------------------------

    def _configure_camera(self) -> None:
        """The settings once, and again after a failed grab (the camera may have been reset)."""
        if not self._camera_configured:
            self.camera.configure(self.settings)
            self._camera_configured = True

    def _grab(self) -> Frame:
        try:
            return self.camera.grab(self.config.camera.grab_timeout_s)
        except DeviceError:
            self._camera_configured = False
            raise

    def _find(self, i: int, frame: Frame, T_b_f: np.ndarray, path: Path | None = None,
              holes: bool = True, seen: ViewsSeen | None = None) -> tuple[Capture, float]:
        """The worker: the expected holes (``holes``) and marks of view ``i`` in ``frame``; (capture, seconds spent
        finding). ``seen`` is told what was found, or which hole or mark was not."""
        start = time.monotonic()
        seen = seen if seen is not None else ViewsSeen()
        pose, view = self.config.measuring_poses[i], self._views[i]
        names, mark_names = self.config.part.point_names, [mark.name for mark in self.config.reference_marks]
        ox, oy = (self.settings.region or (0, 0, 0, 0))[:2]
        bits = bit_depth_of(frame.pixel_format)
        marks = [self._mark_finder.submit(find_mark, frame.image, search, shift, (ox, oy), bits,
                                          f"{pose.name}, mark {self.config.reference_marks[m].name}")
                 for m, search, shift in zip(view.marks, view.mark_searches, view.mark_shifts, strict=True)]
        found: list[tuple[float, float]] = []
        try:
            for j, search in zip(view.points if holes else (), view.holes if holes else (), strict=True):
                (ex, ey), (rx, ry, rw, rh) = search.expected_px, search.roi
                try:
                    hole = measure_hole(frame.image, (ex - ox, ey - oy), search.radius_px,
                                        (rx - ox, ry - oy, rw, rh), max_offset_px=search.max_offset_px, bit_depth=bits)
                except MonoguideError as exc:
                    seen.failed(pose.name, names[j], search.expected_px)
                    raise type(exc)(f"{pose.name}, {names[j]}: {exc.message}") from exc
                found.append((float(hole.center[0]) + ox, float(hole.center[1]) + oy))
            marks_found = []
            for m, search, future in zip(view.marks, view.mark_searches, marks, strict=True):
                try:
                    marks_found.append((m, future.result()))
                except MonoguideError:
                    seen.failed(pose.name, mark_names[m], search.expected_px)
                    raise
        except Exception:
            seen.failed(pose.name)  # not the finder's own refusal (that named its hole or mark above): say where
            raise
        finally:
            for future in marks:
                future.cancel()
        seen.found(i, [(j, names[j], px) for j, px in zip(view.points, found, strict=False)],
                   [(m, mark_names[m], px) for m, px in marks_found])
        seconds = time.monotonic() - start
        first = found[0] if found else (math.nan, math.nan)
        return Capture(i, T_b_f, None if path is None else str(path), first, tuple(found), tuple(found),
                       tuple(marks_found)), seconds

    def _sought(self, i: int) -> tuple[Sought, ...]:
        """Where view ``i``'s holes are sought (the image of each centre over the reference part)."""
        view, names = self._views[i], self.config.part.point_names
        return tuple(Sought(j, names[j], (float(s.expected_px[0]), float(s.expected_px[1])), float(s.radius_px))
                     for j, s in zip(view.points, view.holes, strict=True))

    def _plan_view(self, i: int) -> _View:
        """Where pose ``i``'s holes are sought, over the whole deviation envelope (``ConfigError`` naming the
        pose and the point when one is nowhere in view)."""
        cfg = self.config
        pose, part = cfg.measuring_poses[i], cfg.part
        T_c_w0 = frames.invert(pose.T_cf_si) @ cfg.reference.T_cf_w0
        extremes = search_extremes(_search_envelope(cfg), part.points_w)
        holes = []
        for j in pose.points:
            normal = part.normals_w[j] if part.normals_w is not None else np.array([0.0, 0.0, 1.0])
            search = hole_search(cfg.camera.intrinsics, T_c_w0, part.points_w[j], normal, part.hole_radius_mm,
                                 extremes)
            if search is None:
                raise ConfigError(f"{cfg.path}: measuring pose {pose.name} does not see point {j} anywhere in "
                                  f"the deviation envelope")
            holes.append(search)
        searches, shifts = plan_marks(cfg, pose)
        return _View(pose.points, tuple(holes), pose.marks, tuple(searches), tuple(shifts))


@contextlib.contextmanager
def device_errors(device: str) -> Iterator[None]:
    """A :class:`DeviceError` raised inside names the device it came from (``error.device``), so that the
    service reconnects that device alone and says which one it lost."""
    try:
        yield
    except DeviceError as exc:
        if getattr(exc, "device", None) is None:
            exc.device = device  # type: ignore[attr-defined]
        raise


def _check_abort(abort: threading.Event, abort_error: Callable[[], MonoguideError]) -> None:
    if abort.is_set():
        raise abort_error()


def _residual(problem: PoseProblem, T_s1_w: np.ndarray) -> Residual:
    chi2, dof = residual_chi2(problem, T_s1_w)
    return Residual(chi2, dof, tuple(view_statistics(problem, T_s1_w)))


def _search_envelope(config: CellConfig) -> DeviationEnvelope:
    """How far the part may lie off when the holes are sought: ``[layout]``'s envelope (default +-50 mm,
    +-5 deg), widened to ``[sim.deviation]`` in a simulated cell."""
    envelope = config.layout.envelope if config.layout is not None else DeviationEnvelope()
    if config.sim is None:
        return envelope
    return DeviationEnvelope(
        tuple(max(a, b) for a, b in zip(envelope.translation_mm, config.sim.deviation_translation_mm, strict=True)),
        tuple(max(a, b) for a, b in zip(envelope.rotation_deg, config.sim.deviation_rotation_deg, strict=True)),
        envelope.about_w)
