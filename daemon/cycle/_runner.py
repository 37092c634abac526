"""The work of one measuring cycle, blocking: measure, solve, check, write (docs/cycle.md).

:class:`CycleRunner` holds no asyncio and no PLC: the service (``daemon/service/_loop.py``) calls its four steps in
worker threads and fires the state machine (``daemon/cycle/_states.py``) between them.

- :meth:`CycleRunner.measure` visits every measuring pose: request it, wait until the robot is in position
  (its status carries the actual flange pose, recorded with the capture), grab, and find the hole(s) the
  pose expects in a region of interest predicted from the nominal pose widened by the deviation envelope.
  Finding the holes of view i runs in a worker thread while the robot moves to view i + 1. It returns the
  measurement record of ``docs/measurement-record.md``.
- :meth:`CycleRunner.solve`: the pose (maximum likelihood), one perspective-correction iteration (the
  centre of an imaged hole is not the image of its centre), the checked solve, the base offset ``D_b`` in
  the robot base frame and the quality figures the PLC shows.
- :meth:`CycleRunner.check`: the robot's actual pose at each capture within ``[robot] pose_tolerance_*`` of
  its taught pose, the reprojection RMS, the predicted sigma, the offset envelope (``[checks]``).
- :meth:`CycleRunner.write`: the offset to the robot, acknowledged by its sequence number.

Timings (seconds) go into one dict, ``Measurement.timings_s``, shared with ``Solution.timings_s``:
``robot_motion``, ``exposure``, ``hole_finding`` (measure), ``solve``, ``checks``, ``offset_write`` and
``overhead`` (the last frame in hand -> the offset acknowledged) (write).
"""

from __future__ import annotations

import contextlib
import copy
import itertools
import logging
import math
import re
import threading
import time
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from monoguide.daemon.assembly import taught_flange_poses
from monoguide.daemon.config import CellConfig, ChecksConfig
from monoguide.daemon.errors import CapturePoseMismatch
from monoguide.drivers.camera import Camera, CameraSettings, Frame
from monoguide.drivers.errors import ConfigError, DeviceError
from monoguide.drivers.robot import Robot
from monoguide.solver import frames
from monoguide.solver.errors import MonoguideError, ResidualTooLarge, UncertaintyTooLarge
from monoguide.solver.hole_edges import bit_depth_of
from monoguide.solver.holes import measure_hole, perspective_correction
from monoguide.solver.offset import check_envelope
from monoguide.solver.planning import DeviationEnvelope
from monoguide.solver.planning.prediction import pose_sigmas
from monoguide.solver.pose import solve_ml, solve_pose
from monoguide.solver.record import DEFAULT_SIGMA_PX, FORMAT, MeasurementRecord, parse_record, result_to_dict

log = logging.getLogger(__name__)

ROI_MARGIN_PX = 24.0  # beyond the envelope's spread and the hole's own size
PNG_COMPRESSION = 1  # fast: a 5 MP frame in ~0.1 s
_M_MMAP_THRESHOLD, _M_ARENA_MAX = -3, -8  # glibc mallopt(3) parameters
MMAP_THRESHOLD_BYTES = 1 << 20
MALLOC_ARENAS = 2


def tune_malloc() -> bool:
    """Keep the service's resident memory flat (docs/cycle.md, Memory): at most ``MALLOC_ARENAS`` glibc
    arenas and a fixed mmap threshold of 1 MiB, so every frame-sized buffer (5 MB images, their grey copies)
    is mmapped and returned to the system when freed. Without it glibc raises its mmap threshold after the
    first large free and keeps later frames in per-thread arenas that fragment: the service grew from
    ~250 to over 500 MB in 30 cycles. The same as ``MALLOC_ARENA_MAX=2 MALLOC_MMAP_THRESHOLD_=1048576`` in
    the environment; call it once at start. False when the C library is not glibc (nothing changed)."""
    try:
        import ctypes

        libc = ctypes.CDLL(None)
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    return bool(mallopt(_M_ARENA_MAX, MALLOC_ARENAS)) & bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES))


@dataclass
class Capture:
    """One measuring pose visited."""

    pose_index: int  # 0-based
    T_b_f: np.ndarray  # the robot's actual flange pose at the capture (4x4 mm), from its in-position status
    image_path: str | None  # PNG written under images_dir (None without one)
    centre_px: tuple[float, float]  # the found hole centre (after perspective correction once solved)
    centres_px: tuple[tuple[float, float], ...] = ()  # every expected hole of the view (pose.points order)
    measured_px: tuple[tuple[float, float], ...] = ()  # the same as found: the imaged ellipses' centres


@dataclass
class Measurement:
    """What :meth:`CycleRunner.measure` returns."""

    job: int
    captures: list[Capture]
    record: dict  # the measurement record (docs/measurement-record.md), JSON-able
    timings_s: dict[str, float]
    last_frame_at: float = 0.0  # time.monotonic() when the last frame was in hand
    images: list[Future[bool]] = field(default_factory=list)  # the PNGs being written (True: written)


@dataclass
class Solution:
    """What :meth:`CycleRunner.solve` returns."""

    result: dict  # solver.record.result_to_dict(...), JSON-able
    D_b: np.ndarray  # base offset, robot base frame, 4x4 mm
    offset: tuple[float, float, float, float, float, float]  # x y z mm, A B C deg (KUKA Z-Y'-X'')
    quality: tuple[float, float, float]  # rms px, sigma position mm (grasp point), sigma rotation deg
    timings_s: dict[str, float] = field(default_factory=dict)  # the measurement's own dict
    last_frame_at: float = 0.0
    T_s1_w: np.ndarray | None = None  # the solved pose, unrounded
    images: list[Future[bool]] = field(default_factory=list)  # the measurement's


@dataclass(frozen=True)
class _ViewPlan:
    """Where the holes of one measuring pose are sought."""

    points: tuple[int, ...]
    expected_px: tuple[tuple[float, float], ...]  # at the reference part
    radius_px: tuple[float, ...]
    roi: tuple[tuple[int, int, int, int], ...]  # x, y, w, h, full-sensor px
    max_offset_px: tuple[float, ...]


class CycleRunner:
    """The blocking steps of a cycle on opened devices; one runner serves every cycle on the same camera and
    robot (the service builds a new one when a device was reopened). Building it plans the views (~0.1 s, off
    the cycle's path); the camera is configured at the first :meth:`measure` and again after a failed grab.
    ``images_dir`` may be changed between cycles (the service gives each cycle its own folder).

    The runner owns two worker threads, kept for every cycle (not a new thread per cycle): one finds holes while
    the robot moves, one writes the PNGs off the cycle's path (the last view's image would otherwise sit between
    the last frame and the offset write). :meth:`close` (or leaving ``with``) ends them."""

    def __init__(self, config: CellConfig, camera: Camera, robot: Robot, images_dir: Path | None = None) -> None:
        if config.reference.T_cf_b is None:
            raise ConfigError(f"{config.path}: [reference] T_cf_b: the cycle needs the robot base in the cell frame "
                              f"to give the offset in the robot's frame")
        self.config, self.camera, self.robot, self.images_dir = config, camera, robot, images_dir
        self.checks = config.checks or ChecksConfig()
        c = config.camera
        self.settings = CameraSettings(c.pixel_format, c.exposure_us, c.gain_db, c.region)
        self._taught = taught_flange_poses(config)
        self._template = self._record_template()
        self._views = tuple(self._plan_view(i) for i in range(len(config.measuring_poses)))
        self._camera_configured = False
        self._finder = ThreadPoolExecutor(1, thread_name_prefix="monoguide-holes")
        self._image_writer = ThreadPoolExecutor(1, thread_name_prefix="monoguide-images")

    def close(self) -> None:
        """End the worker threads (a PNG still being written is finished first)."""
        self._finder.shutdown(wait=True, cancel_futures=True)
        self._image_writer.shutdown(wait=True)

    def __enter__(self) -> CycleRunner:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    # --- the four steps ---------------------------------------------------------------------------

    def measure(self, job: int, abort: threading.Event, abort_error: Callable[[], MonoguideError]) -> Measurement:
        """Visit every measuring pose; raise ``abort_error()`` when ``abort`` is set (checked before each
        request and after each wait). ``job`` has been checked by the caller (the service's job rule)."""
        timings = {"robot_motion": 0.0, "exposure": 0.0, "hole_finding": 0.0}
        with device_errors("camera"):
            self._configure_camera()
        poses = self.config.measuring_poses
        futures: list[Future[tuple[Capture, float]]] = []
        last_frame_at = 0.0
        images: list[Future[bool]] = []
        try:
            for i in range(len(poses)):
                _check_abort(abort, abort_error)
                if futures and futures[-1].done():
                    futures[-1].result()  # a view already failed: no need to visit the next one
                t0 = time.monotonic()
                with device_errors("robot"):
                    status = self.robot.move_to_measuring_pose(i)
                t1 = time.monotonic()
                _check_abort(abort, abort_error)
                with device_errors("camera"):
                    frame = self._grab()
                last_frame_at = time.monotonic()
                timings["robot_motion"] += t1 - t0
                timings["exposure"] += last_frame_at - t1
                path = self._image_path(poses[i].name)
                if path is not None:
                    images.append(self._image_writer.submit(_save_png, path, frame.image, poses[i].name))
                futures.append(self._finder.submit(self._find, i, frame, np.array(status.T_b_f, dtype=float), path))
            captures = []
            for future in futures:
                while True:  # every wait has a way out: the abort
                    _check_abort(abort, abort_error)
                    try:
                        capture, seconds = future.result(timeout=0.05)
                        break
                    except TimeoutError:
                        continue
                captures.append(capture)
                timings["hole_finding"] += seconds
        finally:
            for future in futures:
                future.cancel()  # those not started; a running one ends on its own (it only reads its frame)
        record = self._record(job, captures)
        return Measurement(job, captures, record, timings, last_frame_at, images)

    def solve(self, measurement: Measurement) -> Solution:
        """Pose, covariance, one perspective-correction iteration; the measurement's record and captures are
        updated to the corrected centres (so that re-solving the journal's record gives this result:
        ``monoguide journal resolve N --config CELL.toml``, which weights the views at the flange as here)."""
        start = time.monotonic()
        record = self._parse(measurement.record)
        first = solve_ml(record.problem)  # unchecked: its centres are the ellipses', not yet corrected
        corrected = self._corrected_record(measurement, record, first.T_s1_w)
        record = self._parse(corrected)
        result = solve_pose(record.problem, "ml", false_alarm_rate=self.checks.false_alarm_rate)
        elapsed = time.monotonic() - start
        measurement.record = corrected
        displacement = record.displacement(result.T_s1_w)
        assert displacement.base_offset is not None  # the record carries T_b_s1
        D_b = displacement.base_offset
        sigmas = pose_sigmas(result.covariance, result.T_s1_w, record.grasp_point_w)
        measurement.timings_s["solve"] = elapsed
        return Solution(
            result=result_to_dict(record, result, elapsed * 1e3),
            D_b=D_b,
            offset=frames.T_to_kuka_frame(D_b),
            quality=(result.rms_px, sigmas.sigma_trans_mm, sigmas.sigma_rot_deg),
            timings_s=measurement.timings_s,
            last_frame_at=measurement.last_frame_at,
            T_s1_w=result.T_s1_w,
            images=measurement.images,
        )

    def _parse(self, data: dict[str, Any]) -> MeasurementRecord:
        """The record parsed; with ``[camera] T_f_c`` its view sigmas are the robot's repeatability at the
        flange (the camera ~190 mm out moves further than about its own centre), not about the camera."""
        record = parse_record(data)
        T_f_c = self.config.camera.T_f_c
        if T_f_c is None or not (record.problem.view_sigma_mm or record.problem.view_sigma_deg):
            return record
        return replace(record, problem=record.problem.with_flange(T_f_c))

    def check(self, measurement: Measurement, solution: Solution) -> None:
        """Raise the first failing check's error: the robot's pose at each capture
        (:class:`CapturePoseMismatch`), the RMS (``RESIDUAL_TOO_LARGE``), the predicted sigma
        (``UNCERTAINTY_TOO_LARGE``), the offset envelope (``OFFSET_OUT_OF_ENVELOPE``)."""
        start = time.monotonic()
        try:
            self._check_capture_poses(measurement)
            c = self.checks
            rms, sigma_mm, sigma_deg = solution.quality
            if not rms <= c.max_rms_px:
                raise ResidualTooLarge(f"reprojection RMS {rms:.3f} px above [checks] max_rms_px = {c.max_rms_px:g}")
            if not (sigma_mm <= c.max_sigma_mm and sigma_deg <= c.max_sigma_deg):
                raise UncertaintyTooLarge(
                    f"predicted sigma {sigma_mm:.3f} mm at the grasp point / {sigma_deg:.4f} deg above [checks] "
                    f"max_sigma_mm = {c.max_sigma_mm:g} / max_sigma_deg = {c.max_sigma_deg:g}")
            record = parse_record(measurement.record)
            T_s1_w = solution.T_s1_w if solution.T_s1_w is not None else np.array(solution.result["T_s1_w"])
            check_envelope(record.displacement(T_s1_w), record.envelope)
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

    def _find(self, i: int, frame: Frame, T_b_f: np.ndarray, path: Path | None = None) -> tuple[Capture, float]:
        """The worker: the expected holes of view ``i`` in ``frame``; (capture, seconds spent finding)."""
        start = time.monotonic()
        pose, view = self.config.measuring_poses[i], self._views[i]
        ox, oy = (self.settings.region or (0, 0, 0, 0))[:2]
        bits = bit_depth_of(frame.pixel_format)
        found = []
        for j, expected, r_px, roi, max_offset in zip(view.points, view.expected_px, view.radius_px, view.roi,
                                                      view.max_offset_px, strict=True):
            try:
                hole = measure_hole(frame.image, (expected[0] - ox, expected[1] - oy), r_px,
                                    (roi[0] - ox, roi[1] - oy, roi[2], roi[3]), max_offset_px=max_offset,
                                    bit_depth=bits)
            except MonoguideError as exc:
                raise type(exc)(f"{pose.name}, {self.config.part.point_names[j]}: {exc.message}") from exc
            found.append((float(hole.center[0]) + ox, float(hole.center[1]) + oy))
        seconds = time.monotonic() - start
        return Capture(i, T_b_f, None if path is None else str(path), found[0], tuple(found), tuple(found)), seconds

    def _image_path(self, name: str) -> Path | None:
        if self.images_dir is None:
            return None
        return Path(self.images_dir) / f"{re.sub(r'[^A-Za-z0-9_.-]', '_', name)}.png"

    # --- the record ---------------------------------------------------------------------------------

    def _record_template(self) -> dict[str, Any]:
        """Everything of the record but its id, views and observations: the cell's calibration, in SF1."""
        cfg = self.config
        T_cf_s1 = cfg.measuring_poses[0].T_cf_si
        T_s1_cf = frames.invert(T_cf_s1)
        layout = cfg.layout
        record: dict[str, Any] = {
            "format": FORMAT,
            "camera": {k: float(v) if k not in ("width", "height") else int(v)
                       for k, v in cfg.camera.intrinsics.as_dict().items()},
            "points_w": cfg.part.points_w.tolist(),
            "views": [{"T_s1_si": (T_s1_cf @ p.T_cf_si).tolist()} for p in cfg.measuring_poses],
            "T_s1_w0": (T_s1_cf @ cfg.reference.T_cf_w0).tolist(),
            "sigma_px": layout.sigma_px if layout is not None else DEFAULT_SIGMA_PX,
        }
        if layout is not None and (layout.repeatability_mm > 0 or layout.repeatability_deg > 0):
            record["view_sigma"] = {"mm": layout.repeatability_mm, "deg": layout.repeatability_deg}
        assert cfg.reference.T_cf_b is not None
        record["T_b_s1"] = (frames.invert(cfg.reference.T_cf_b) @ T_cf_s1).tolist()
        grasp = cfg.part.grasp_point_w if cfg.part.grasp_point_w is not None else cfg.part.points_w.mean(axis=0)
        record["grasp_point_w"] = [float(v) for v in grasp]
        record["envelope"] = self._envelope()
        return record

    def _envelope(self) -> dict[str, Any]:
        """The offset envelope: ``[checks]``, else ``[layout]``'s (totals: the norms of its per-axis limits),
        else the record's default."""
        c, layout = self.checks, self.config.layout
        axis_mm = c.envelope_axis_mm or (layout.envelope.translation_mm if layout is not None else None)
        axis_deg = c.envelope_axis_deg or (layout.envelope.rotation_deg if layout is not None else None)
        total_mm = c.envelope_mm or (float(np.linalg.norm(axis_mm)) if axis_mm else 50.0)
        total_deg = c.envelope_deg or (float(np.linalg.norm(axis_deg)) if axis_deg else 5.0)
        out: dict[str, Any] = {"mm": total_mm, "deg": total_deg}
        if axis_mm:
            out["axis_mm"] = [float(v) for v in axis_mm]
        if axis_deg:
            out["axis_deg"] = [float(v) for v in axis_deg]
        return out

    def _record(self, job: int, captures: list[Capture]) -> dict[str, Any]:
        observations = []
        for capture in captures:
            points = self.config.measuring_poses[capture.pose_index].points
            for j, px in zip(points, capture.centres_px, strict=True):
                observations.append({"view": capture.pose_index, "point": int(j), "pixel": [px[0], px[1]]})
        stamp = time.strftime("%Y%m%dT%H%M%S", time.gmtime())
        T_cf_si = self._camera_poses(captures)
        T_s1_cf = frames.invert(T_cf_si[0])
        assert self.config.reference.T_cf_b is not None
        return {**copy.deepcopy(self._template), "id": f"job{job}-{stamp}-{time.monotonic_ns() % 1_000_000:06d}",
                "views": [{"T_s1_si": (T_s1_cf @ T).tolist()} for T in T_cf_si],
                "T_s1_w0": (T_s1_cf @ self.config.reference.T_cf_w0).tolist(),
                "T_b_s1": (frames.invert(self.config.reference.T_cf_b) @ T_cf_si[0]).tolist(),
                "observations": observations}

    def _camera_poses(self, captures: list[Capture]) -> list[np.ndarray]:
        """``T_cf_si`` of each capture: the calibrated camera pose moved by how far the robot's reported flange
        pose stood off the taught one (its repeatability), ``T_cf_si inv(T_f_c) inv(T_b_f_taught) T_b_f T_f_c``;
        the calibrated pose itself when the config has no ``[camera] T_f_c`` or no taught poses."""
        T_f_c = self.config.camera.T_f_c
        out = []
        for capture in sorted(captures, key=lambda c: c.pose_index):
            T_cf_si = self.config.measuring_poses[capture.pose_index].T_cf_si
            if T_f_c is not None and self._taught:
                stand_off = frames.invert(self._taught[capture.pose_index]) @ capture.T_b_f
                T_cf_si = T_cf_si @ frames.invert(T_f_c) @ stand_off @ T_f_c
            out.append(T_cf_si)
        return out

    def _corrected_record(self, measurement: Measurement, record: MeasurementRecord,
                          T_s1_w: np.ndarray) -> dict[str, Any]:
        """The record with each centre moved from the imaged ellipse's centre to the image of the hole's
        centre, the difference predicted at ``T_s1_w``; the captures' ``centre_px`` follow."""
        part = self.config.part
        problem = record.problem
        pixels = {}
        for capture in measurement.captures:
            T_c_w = frames.invert(problem.T_s1_si[capture.pose_index]) @ T_s1_w
            points = self.config.measuring_poses[capture.pose_index].points
            corrected = []
            for j, measured in zip(points, capture.measured_px, strict=True):
                normal = part.normals_w[j] if part.normals_w is not None else np.array([0.0, 0.0, 1.0])
                try:
                    shift = perspective_correction(problem.camera, T_c_w, part.points_w[j], normal,
                                                   part.hole_radius_mm)
                except ValueError:  # not in front of the camera at this pose: no correction
                    shift = np.zeros(2)
                px = (measured[0] - float(shift[0]), measured[1] - float(shift[1]))
                corrected.append(px)
                pixels[(capture.pose_index, int(j))] = px
            capture.centres_px = tuple(corrected)
            capture.centre_px = corrected[0]
        observations = [{**o, "pixel": list(pixels[(o["view"], o["point"])])}
                        for o in measurement.record["observations"]]
        return {**measurement.record, "observations": observations}

    # --- checking -----------------------------------------------------------------------------------

    def _check_capture_poses(self, measurement: Measurement) -> None:
        r = self.config.robot
        if r is None or not self._taught:
            return
        for capture in measurement.captures:
            angle_deg, distance_mm = frames.pose_difference(capture.T_b_f, self._taught[capture.pose_index])
            if distance_mm > r.pose_tolerance_mm or angle_deg > r.pose_tolerance_deg:
                name = self.config.measuring_poses[capture.pose_index].name
                raise CapturePoseMismatch(
                    f"{name}: the robot stood {distance_mm:.3f} mm / {angle_deg:.4f} deg from the taught flange pose "
                    f"at the capture ([robot] pose_tolerance_mm = {r.pose_tolerance_mm:g}, pose_tolerance_deg = "
                    f"{r.pose_tolerance_deg:g}): nothing is written")

    # --- planning the search ------------------------------------------------------------------------

    def _plan_view(self, i: int) -> _ViewPlan:
        """Project the pose's holes at the reference part and over the corners of the deviation envelope:
        the region of interest spans them all, plus the hole and a margin."""
        cfg = self.config
        pose, camera = cfg.measuring_poses[i], cfg.camera.intrinsics
        T_c_cf = frames.invert(pose.T_cf_si)
        deviations = _envelope_corners(_search_envelope(cfg), cfg.part.points_w)
        expected, radii, rois, offsets = [], [], [], []
        for j in pose.points:
            p_w = cfg.part.points_w[j]
            p_c = frames.transform_points(T_c_cf @ cfg.reference.T_cf_w0, p_w[None])[0]
            centre = camera.project(p_c[None])[0]
            normal_w = cfg.part.normals_w[j] if cfg.part.normals_w is not None else np.array([0.0, 0.0, 1.0])
            normal_c = (T_c_cf @ cfg.reference.T_cf_w0)[:3, :3] @ (normal_w / np.linalg.norm(normal_w))
            cos_view = abs(float(normal_c @ p_c) / float(np.linalg.norm(p_c)))
            r_px = cfg.part.hole_radius_mm * math.sqrt(camera.fx * camera.fy) / p_c[2] * math.sqrt(cos_view)
            q_w0 = np.einsum("kij,j->ki", deviations[:, :3, :3], p_w) + deviations[:, :3, 3]
            q_c = frames.transform_points(T_c_cf @ cfg.reference.T_cf_w0, q_w0)
            pts = np.vstack([camera.project(q_c[q_c[:, 2] > 0]).reshape(-1, 2), centre[None]])
            pad = 2.0 * r_px + ROI_MARGIN_PX
            x0, y0 = np.floor(pts.min(axis=0) - pad)
            x1, y1 = np.ceil(pts.max(axis=0) + pad)
            x0, y0 = max(int(x0), 0), max(int(y0), 0)
            x1, y1 = min(int(x1), camera.width), min(int(y1), camera.height)
            if x1 - x0 < 1 or y1 - y0 < 1:
                raise ConfigError(f"{cfg.path}: measuring pose {pose.name} does not see point {j} anywhere in "
                                  f"the deviation envelope")
            expected.append((float(centre[0]), float(centre[1])))
            radii.append(float(r_px))
            rois.append((x0, y0, x1 - x0, y1 - y0))
            offsets.append(float(np.max(np.linalg.norm(pts - centre, axis=1))) + r_px + ROI_MARGIN_PX)
        return _ViewPlan(pose.points, tuple(expected), tuple(radii), tuple(rois), tuple(offsets))


def _save_png(path: Path, image: np.ndarray, name: str) -> bool:
    """The image writer's job: ``image`` as PNG at ``path``; False (and a warning) when it cannot."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        if cv2.imwrite(str(path), image, [cv2.IMWRITE_PNG_COMPRESSION, PNG_COMPRESSION]):
            return True
    except (OSError, cv2.error) as exc:
        log.warning("cannot save the image of %s at %s: %s", name, path, exc)
        return False
    log.warning("cannot save the image of %s at %s", name, path)
    return False


def wait_images(images: list[Future[bool]], timeout_s: float = 10.0) -> bool:
    """Wait (at most ``timeout_s`` in all) until the cycle's PNGs are written; True when all were."""
    deadline = time.monotonic() + timeout_s
    ok = True
    for future in images:
        try:
            ok &= bool(future.result(timeout=max(deadline - time.monotonic(), 0.0)))
        except TimeoutError:
            log.warning("images: still writing after %.0f s", timeout_s)
            return False
    return ok


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


def _search_envelope(config: CellConfig) -> DeviationEnvelope:
    """How far the part may lie off when the holes are sought: ``[layout]``'s envelope (default +-50 mm,
    +-5 deg), widened to ``[sim.deviation]`` in a simulated cell."""
    envelope = config.layout.envelope if config.layout is not None else DeviationEnvelope()
    if config.sim is None:
        return envelope
    return DeviationEnvelope(
        tuple(max(a, b) for a, b in zip(envelope.translation_mm, config.sim.deviation_translation_mm, strict=True)),
        tuple(max(a, b) for a, b in zip(envelope.rotation_deg, config.sim.deviation_rotation_deg, strict=True)),
        envelope.centre_w)


def _envelope_corners(envelope: DeviationEnvelope, points_w: np.ndarray) -> np.ndarray:
    """``T_w0_w`` of the envelope's extremes: every corner of the translation box with every rotation vector
    of -1, 0, +1 times the rotation limits (about the envelope's centre)."""
    c = envelope.centre(points_w)
    t_lim, r_lim = np.asarray(envelope.translation_mm, float), np.radians(np.asarray(envelope.rotation_deg, float))
    out = []
    for t_sign in itertools.product((-1.0, 1.0), repeat=3):
        for r_sign in itertools.product((-1.0, 0.0, 1.0), repeat=3):
            R = frames.rotvec_to_matrix(np.asarray(r_sign) * r_lim)
            out.append(frames.make_T(R, c - R @ c + np.asarray(t_sign) * t_lim))
    return np.array(out)
