"""What a cycle measured and solved, and its measurement record (docs/measurement-record.md).

:class:`RecordBuilder` knows the cell's calibration in the record's terms (SF1, the first camera pose): it builds
the record of a cycle's captures once, parsed at once (:class:`Measurement` carries both the JSON object the
journal keeps and the typed record the solve and the checks use), and moves its centres to the images of the
holes' centres once the pose is known (the perspective correction).
"""

from __future__ import annotations

import copy
import time
from concurrent.futures import Future
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from monoguide.daemon.config import CellConfig, ChecksConfig
from monoguide.daemon.cycle._residual import Residual
from monoguide.solver import frames
from monoguide.solver.holes import perspective_correction
from monoguide.solver.marks_problem import CALIBRATION_SIGMA_DEG, CALIBRATION_SIGMA_MM
from monoguide.solver.offset import PartDisplacement
from monoguide.solver.record import DEFAULT_SIGMA_PX, FORMAT, MeasurementRecord, envelope_to_record, parse_record


@dataclass
class Capture:
    """One measuring pose visited."""

    pose_index: int  # 0-based
    T_b_f: np.ndarray  # the robot's actual flange pose at the capture (4x4 mm), from its in-position status
    image_path: str | None  # PNG written under images_dir (None without one)
    centre_px: tuple[float, float]  # the found hole centre (after perspective correction once solved)
    centres_px: tuple[tuple[float, float], ...] = ()  # every expected hole of the view (pose.points order)
    measured_px: tuple[tuple[float, float], ...] = ()  # the same as found: the imaged ellipses' centres
    marks_px: tuple[tuple[int, tuple[float, float]], ...] = ()  # (mark, image of its centre, corrected) per mark


@dataclass
class Measurement:
    """What :meth:`CycleRunner.measure` returns: the captures, the record (as the journal keeps it, and parsed)."""

    job: int
    captures: list[Capture]
    record: dict[str, Any]  # the measurement record (docs/measurement-record.md), JSON-able
    parsed: MeasurementRecord  # the same, typed: what the solve and the checks use (None: a check of marks alone)
    timings_s: dict[str, float]
    last_frame_at: float = 0.0  # time.monotonic() when the last frame was in hand
    images: list[Future[bool]] = field(default_factory=list)  # the PNGs being written (True: written)


@dataclass
class Solution:
    """What :meth:`CycleRunner.solve` returns."""

    result: dict[str, Any]  # solver.record.result_to_dict(...), JSON-able
    D_b: np.ndarray  # base offset, robot base frame, 4x4 mm
    offset: tuple[float, float, float, float, float, float]  # x y z mm, A B C deg (KUKA Z-Y'-X'')
    quality: tuple[float, float, float]  # rms px, sigma position mm (grasp point), sigma rotation deg
    timings_s: dict[str, float] = field(default_factory=dict)  # the measurement's own dict
    last_frame_at: float = 0.0
    T_s1_w: np.ndarray | None = None  # the solved pose, unrounded
    displacement: PartDisplacement | None = None  # of the part from the reference (the envelope is judged on it)
    images: list[Future[bool]] = field(default_factory=list)  # the measurement's
    residual: Residual | None = None  # for the trend monitor (docs/health.md)


class RecordBuilder:
    """The measurement records of one cell config."""

    def __init__(self, config: CellConfig, checks: ChecksConfig, taught: tuple[np.ndarray, ...]) -> None:
        self.config, self.checks, self.taught = config, checks, taught
        self._template = self._record_template()

    def measurement(self, job: int, captures: list[Capture], timings_s: dict[str, float], last_frame_at: float,
                    images: list[Future[bool]]) -> Measurement:
        """The cycle's record, built and parsed once (the view sigmas at the flange with ``[camera] T_f_c``)."""
        record = self._record(job, captures)
        return Measurement(job, captures, record, parse_record(record, self.config.camera.T_f_c), timings_s,
                           last_frame_at, images)

    def marks_measurement(self, job: int, captures: list[Capture], timings_s: dict[str, float],
                          last_frame_at: float, images: list[Future[bool]]) -> Measurement:
        """The record of a visit that measured the marks alone (the check job with marks): no hole observations,
        not parsed (``parsed`` None)."""
        return Measurement(job, captures, self._record(job, captures), None, timings_s,  # type: ignore[arg-type]
                           last_frame_at, images)

    def correct(self, measurement: Measurement, T_s1_w: np.ndarray) -> MeasurementRecord:
        """Move each centre from the imaged ellipse's centre to the image of the hole's centre, the difference
        predicted at ``T_s1_w``; the captures, the record and the parsed record follow (returned)."""
        part, parsed = self.config.part, measurement.parsed
        problem = parsed.problem
        pixels: dict[tuple[int, int], tuple[float, float]] = {}
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
        measurement.record = {**measurement.record, "observations": observations}
        moved = np.array([pixels[(int(v), int(p))] for v, p in zip(problem.view_index, problem.point_index,
                                                                   strict=True)])
        measurement.parsed = replace(parsed, problem=problem.with_pixels(moved))
        return measurement.parsed

    # --- private ------------------------------------------------------------------------------------

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
            "views": [{"T_s1_si": (T_s1_cf @ p.T_cf_si).tolist(), "name": p.name} for p in cfg.measuring_poses],
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
        """The part's one envelope (``[checks]`` over its ``[layout]``'s, solver/envelope.py) in the record's form,
        about its point (the holes' centroid unless ``envelope_centre_w`` says otherwise)."""
        layout = self.config.layout
        envelope = self.checks.envelope(layout.envelope if layout is not None else None)
        return envelope_to_record(envelope.at(self.config.part.points_w))

    def _record(self, job: int, captures: list[Capture]) -> dict[str, Any]:
        observations = []
        for capture in captures:
            points = self.config.measuring_poses[capture.pose_index].points
            for j, px in zip(points if capture.centres_px else (), capture.centres_px, strict=True):
                observations.append({"view": capture.pose_index, "point": int(j), "pixel": [px[0], px[1]]})
        stamp = time.strftime("%Y%m%dT%H%M%S", time.gmtime())
        T_cf_si = self._camera_poses(captures)
        T_s1_cf = frames.invert(T_cf_si[0])
        assert self.config.reference.T_cf_b is not None
        poses = self.config.measuring_poses
        return {**copy.deepcopy(self._template), "id": f"job{job}-{stamp}-{time.monotonic_ns() % 1_000_000:06d}",
                "job": job, "part": self.config.part_name,
                "views": [{"T_s1_si": (T_s1_cf @ T).tolist(), "name": poses[c.pose_index].name}
                          for T, c in zip(T_cf_si, sorted(captures, key=lambda c: c.pose_index), strict=True)],
                "T_s1_w0": (T_s1_cf @ self.config.reference.T_cf_w0).tolist(),
                "T_b_s1": (frames.invert(self.config.reference.T_cf_b) @ T_cf_si[0]).tolist(),
                "observations": observations, **self._marks(captures, T_s1_cf)}

    def _marks(self, captures: list[Capture], T_s1_cf: np.ndarray) -> dict[str, Any]:
        """The record's marks (surveyed centres in this cycle's SF1) and their sightings; nothing in a cell whose
        poses list no marks."""
        seen = sorted({m for c in captures for m, _ in c.marks_px})
        if not seen:
            return {}
        marks = self.config.reference_marks
        index = {m: k for k, m in enumerate(seen)}
        return {
            "marks": [{"name": marks[m].name, "sigma_mm": marks[m].sigma_mm,
                       "position_s1": frames.transform_points(T_s1_cf, marks[m].position_cf[None])[0].tolist()}
                      for m in seen],
            "mark_observations": [{"view": c.pose_index, "mark": index[m], "pixel": [px[0], px[1]]}
                                  for c in captures for m, px in c.marks_px],
            "calibration_sigma": {"mm": CALIBRATION_SIGMA_MM, "deg": CALIBRATION_SIGMA_DEG},
        }

    def _camera_poses(self, captures: list[Capture]) -> list[np.ndarray]:
        """``T_cf_si`` of each capture: the calibrated camera pose moved by how far the robot's reported flange
        pose stood off the taught one (its repeatability), ``T_cf_si inv(T_f_c) inv(T_b_f_taught) T_b_f T_f_c``;
        the calibrated pose itself when the config has no ``[camera] T_f_c`` or no taught poses."""
        T_f_c = self.config.camera.T_f_c
        out = []
        for capture in sorted(captures, key=lambda c: c.pose_index):
            T_cf_si = self.config.measuring_poses[capture.pose_index].T_cf_si
            if T_f_c is not None and self.taught:
                stand_off = frames.invert(self.taught[capture.pose_index]) @ capture.T_b_f
                T_cf_si = T_cf_si @ frames.invert(T_f_c) @ stand_off @ T_f_c
            out.append(T_cf_si)
        return out
