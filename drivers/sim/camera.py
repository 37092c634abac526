"""The simulated flange camera: renders the part's featured holes as the cell's truth has them.

Each :meth:`SimCamera.grab` renders the holes of the current part (``SimCell.T_cf_w_true``) seen from the
robot's actual pose (``SimCell.actual_camera_pose()``) through the cell's camera model, with the hole
renderer's blur, noise and uneven light. Exposure and gain change the brightness. It can be told to fail
(:meth:`SimCamera.fail_next`): ``timeout``, ``disconnect``, ``black`` frame, hole ``occluded``, ``glare``.

With ``follow`` (the state file of a running ``monoguide sim-cell``) the camera lives in the daemon's process
but sees the simulated robot of the sim-cell's controller process: before every grab it reads the state
file's ``robot.truth`` and stands where that robot stands, with the part its part supply presents
(:func:`~monoguide.drivers.sim.robot_motion.follow_truth`); and it applies the state file's
``camera_fault`` (``{"failure", "count", "serial"}``, written on a ``camera <failure> [count]`` command to
sim-cell) once per ``serial``. A fault already in the file when the camera opens is history, not applied.
Without a state file (no sim-cell running) it renders its own cell as without ``follow``.

Calibration faults (:mod:`~monoguide.drivers.sim.calibration_faults`: the camera bumped on its bracket, its lens's
focal length changed, a measuring pose that stops elsewhere while the robot reports the taught pose) persist:
the entry ``camera_fault.calibration`` of the state file (``camera bump|focal ...``, ``pose drift ...`` to
sim-cell) holds the ones the cell has now, read before every grab (one there when the camera opens applies: it is
the state of the cell, not an event), and :meth:`SimCamera.set_calibration_faults` sets them without a sim-cell.
The part's holes are rendered through them (the scene mode's targets and plate are not).

Reference marks: the cell's fixed marks (``SimCellSpec.marks``, the config's ``[[reference_marks]]``) are rendered
with the holes, in the same rendering (blur, defocus at their own depth, noise, light, exposure and calibration
faults apply to them exactly as to the holes): each a dark disc in its own plane, where the true camera sees it.
A mark the part's sheet hides is not drawn: one whose line of sight (the segment from the camera centre to the
mark's centre) crosses the plane of the current part's outline (``SimCellSpec.outline_w``, at its true pose)
inside the outline; without an outline the part hides nothing. Only marks in front of the camera and (partly) in
the image are drawn. :attr:`SimCamera.last_marks` keeps each mark's ground truth (:class:`MarkTruth`). The
``occluded`` failure still covers the holes only.

Scene mode (``monoguide calibrate --sim``): when the cell has a :class:`~monoguide.drivers.sim.cell.SimScene`
(set by the simulated operator), the camera renders what is in front of it: the circle plate held in view,
else a calibration target lying under it (its circular marks,
:func:`~monoguide.drivers.sim.target_renderer.render_target`), else the part's holes as always, the part where
the scene put it (not where the robot's part supply would).
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from monoguide.drivers.camera import CameraIdentity, CameraSettings, Frame
from monoguide.drivers.errors import DeviceDisconnected, DeviceSettingRejected, DeviceTimeout
from monoguide.drivers.sim.calibration_faults import CalibrationFaults
from monoguide.drivers.sim.cell import SimCell, SimScene
from monoguide.drivers.sim.hole_renderer import Glare, HoleSpec, RenderedView, RenderSettings, render_view
from monoguide.drivers.sim.robot_motion import follow_truth
from monoguide.drivers.sim.target_renderer import RenderedTarget, TargetRenderSettings, render_target
from monoguide.solver.camera import CameraModel
from monoguide.solver.frames import compose, invert, make_T, transform_points

log = logging.getLogger(__name__)

FAILURES = ("timeout", "disconnect", "black", "occluded", "glare")
MAX_SIM_TIMEOUT_S = 0.2  # a simulated timeout waits at most this long before raising
_MARK_RIM_POINTS = 256  # a mark's rim is projected at this many points for its box in the image
_MARK_FOV_FACTOR = 1.5  # marks within this factor of the image's reach are looked at (beyond, the lens model may fold)


@dataclass(frozen=True, eq=False)
class MarkTruth:
    """Ground truth of one reference mark in the last grab (:attr:`SimCamera.last_marks`).

    ``center_px`` (2,): the exact projection of the mark's 3-D centre through the true lens at the true camera pose
    (calibration faults included), raw full-sensor pixels (NaN when it is behind the camera); ``depth_mm``: the
    centre's camera z; ``hidden``: the part's sheet lies on the line of sight to its centre; ``rendered``: drawn
    (in front of the camera, its rim (partly) in the image, not hidden); ``in_view``: drawn and its whole rim in
    the image."""

    name: str
    center_px: np.ndarray
    depth_mm: float
    hidden: bool
    rendered: bool
    in_view: bool


class SimCamera:
    """:class:`~monoguide.drivers.camera.Camera` reading a :class:`SimCell`. ``last_view`` keeps the last
    rendering's ground truth (``centers_px`` in full-sensor pixels, ``in_view``: the holes'), ``last_marks`` the
    reference marks' (mark name -> :class:`MarkTruth`; empty when the last grab showed a calibration scene)."""

    def __init__(self, cell: SimCell, render: RenderSettings | None = None, seed: int | None = None,
                 follow: Path | None = None) -> None:
        self.cell = cell
        self.follow = follow
        self._fault_serial: int | None = None
        render = render or RenderSettings()
        if render.focus_distance_mm is None and cell.spec.focus_distance_mm is not None:  # the cell's own lens
            render = replace(render, focus_distance_mm=cell.spec.focus_distance_mm, aperture_mm=cell.spec.aperture_mm)
        self.render = render
        self.rng = np.random.default_rng(cell.spec.seed + 1 if seed is None else seed)
        self.settings = CameraSettings()
        self.last_view: RenderedView | RenderedTarget | None = None
        self.last_marks: dict[str, MarkTruth] = {}
        self.target_render = TargetRenderSettings()
        self._open = False
        self._frames = 0
        self._failures: list[str] = []
        self.calibration_faults = CalibrationFaults()
        self._calibration_serial: int | None = None
        self._identity = CameraIdentity("monoguide", "SimCamera", f"SIM-{cell.spec.seed}", None, "1.0")

    @property
    def identity(self) -> CameraIdentity | None:
        return self._identity if self._open else None

    def open(self) -> CameraIdentity:
        if self.follow is not None:
            fault = self._read_state().get("camera_fault")
            self._fault_serial = _serial(fault)
        self._open = True
        self._frames = 0
        return self._identity

    def configure(self, settings: CameraSettings) -> None:
        self._require_open()
        if settings.pixel_format != "Mono8":
            raise DeviceSettingRejected(f"sim camera: pixel format {settings.pixel_format!r}; it offers ['Mono8']")
        cam = self.cell.camera
        if settings.region is not None:
            ox, oy, w, h = settings.region
            if ox < 0 or oy < 0 or w <= 0 or h <= 0 or ox + w > cam.width or oy + h > cam.height:
                raise DeviceSettingRejected(f"sim camera: region {settings.region} outside the "
                                            f"{cam.width} x {cam.height} sensor")
        self.settings = settings

    def fail_next(self, failure: str, count: int = 1) -> None:
        """Make the next ``count`` grabs fail with ``failure`` (one of :data:`FAILURES`)."""
        if failure not in FAILURES:
            raise ValueError(f"failure {failure!r} must be one of {FAILURES}")
        self._failures.extend([failure] * count)

    def set_calibration_faults(self, faults: CalibrationFaults) -> None:
        """From the next grab on, render through ``faults`` (until set again; ``CalibrationFaults()``: none)."""
        self.calibration_faults = faults

    def grab(self, timeout_s: float) -> Frame:
        self._require_open()
        if self.follow is not None:
            self._follow_cell()
        failure = self._failures.pop(0) if self._failures else None
        if failure == "timeout":
            time.sleep(min(timeout_s, MAX_SIM_TIMEOUT_S))
            raise DeviceTimeout(f"sim camera: no frame within {timeout_s:g} s (simulated)")
        if failure == "disconnect":
            self._open = False
            raise DeviceDisconnected("sim camera: device gone (simulated unplug)")
        view = self._render(failure)
        self.last_view = view
        image = view.image
        if self.settings.region is not None:
            ox, oy, w, h = self.settings.region
            image = image[oy : oy + h, ox : ox + w]
        self._frames += 1
        return Frame(np.ascontiguousarray(image), self._frames, time.time(), "Mono8")

    def close(self) -> None:
        self._open = False

    # --- private -------------------------------------------------------------------------------

    def _read_state(self) -> dict[str, Any]:
        """The sim-cell state file; empty when there is none (no sim-cell runs: the camera sees its own cell)."""
        assert self.follow is not None
        try:
            state = json.loads(Path(self.follow).read_text())
        except FileNotFoundError:
            return {}
        except (OSError, ValueError) as exc:
            raise DeviceDisconnected(f"sim camera: cannot read the sim-cell state file {self.follow}: {exc} "
                                     f"(is `monoguide sim-cell` running?)") from exc
        if not isinstance(state, dict):
            raise DeviceDisconnected(f"sim camera: {self.follow} is not a sim-cell state file")
        return state

    def _follow_cell(self) -> None:
        """Stand where the sim-cell's robot stands, see its part, and take up a newly commanded fault."""
        state = self._read_state()
        fault = state.get("camera_fault")
        serial = _serial(fault)
        if serial is not None and serial != self._fault_serial:
            self._fault_serial = serial
            try:
                self.fail_next(str(fault["failure"]), int(fault.get("count", 1)))  # type: ignore[index,union-attr]
                log.info("sim camera: %s for the next %s grabs (fault %d)", fault["failure"],  # type: ignore[index]
                         fault.get("count", 1), serial)  # type: ignore[union-attr]
            except (ValueError, TypeError, KeyError) as exc:
                log.warning("sim camera: ignoring camera_fault %r: %s", fault, exc)
        self._take_calibration_faults(fault.get("calibration") if isinstance(fault, dict) else None)
        truth = (state.get("robot") or {}).get("truth")
        if not truth:  # no sim-cell (or one without a robot): the camera's own cell, at its own pose
            return
        try:
            follow_truth(self.cell, Path(truth))
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise DeviceDisconnected(f"sim camera: cannot follow the simulated robot ({truth}): {exc}") from exc

    def _take_calibration_faults(self, entry: object) -> None:
        """The state file's calibration faults become the camera's (a malformed entry: logged, the last kept)."""
        serial = _serial(entry)
        try:
            faults = CalibrationFaults.from_state(entry)
        except (ValueError, TypeError, KeyError) as exc:
            if serial != self._calibration_serial:
                log.warning("sim camera: ignoring calibration faults %r: %s", entry, exc)
                self._calibration_serial = serial
            return
        if serial != self._calibration_serial:
            log.info("sim camera: calibration faults now %s (fault %s)", faults, serial)
            self._calibration_serial = serial
        self.calibration_faults = faults

    def _render(self, failure: str | None) -> RenderedView | RenderedTarget:
        cell = self.cell
        self.last_marks = {}
        if cell.scene is not None:
            if cell.scene.part is not None:  # the part the operator put there, whatever the part supply says
                cell.set_part_pose(cell.scene.part)
            if failure in (None, "black") and (shown := self._render_scene(cell.scene, failure)) is not None:
                return shown
        holes = [HoleSpec(center_w=p, radius_mm=cell.spec.hole_radius_mm) for p in cell.spec.points_w]
        settings = replace(self.render, exposure=self._exposure_factor(failure))
        faults = self.calibration_faults
        T_c_w = faults.T_c_w(cell) if faults.active else cell.T_c_w_true()
        lens = faults.true_camera(cell.camera) if faults.focal_pct else cell.camera
        if failure == "glare":
            centre = _first_in_image(cell, T_c_w, holes)
            settings = replace(settings, glare=Glare(center_px=centre, sigma_px=60.0, peak_grey=400.0))
        marks, self.last_marks = self._marks_seen(lens, T_c_w)
        view = render_view(lens, T_c_w, holes, settings, self.rng, clutter=marks)  # the marks: no hole truth
        if failure == "occluded":
            # something (a cable, a gripper finger) lies over the hole: sheet-grey disc at the hole
            r = int(3.0 * cell.spec.hole_radius_mm * cell.camera.fx / max(float(T_c_w[2, 3]), 1.0)) + 8
            grey = int(np.clip(settings.sheet_grey * settings.exposure, 0, 255))
            for (u, v), seen in zip(view.centers_px, view.in_view, strict=True):
                if seen:
                    cv2.circle(view.image, (round(u), round(v)), r, grey, thickness=-1)
        return view

    def _marks_seen(self, lens: CameraModel, T_c_w: np.ndarray) -> tuple[list[HoleSpec], dict[str, MarkTruth]]:
        """The reference marks to draw, in the part frame W (``T_c_w``: the true camera's view of the part), and
        every mark's truth. A mark is expressed in W through the true part pose: ``T_w_cf = inv(T_cf_w_true)``."""
        marks = self.cell.spec.marks
        if not marks:
            return [], {}
        T_w_cf = invert(self.cell.T_cf_w_true)
        R, t = T_w_cf[:3, :3], T_w_cf[:3, 3]
        centers_w = np.array([m.position_cf for m in marks], dtype=float).reshape(-1, 3) @ R.T + t
        radii = np.array([m.radius_mm for m in marks], dtype=float)
        centers_c = centers_w @ T_c_w[:3, :3].T + T_c_w[:3, 3]
        depth = centers_c[:, 2]
        ahead = depth > 0
        centers_px = np.full((len(marks), 2), np.nan)
        if np.any(ahead):
            centers_px[ahead] = lens.project(centers_c[ahead])
        hidden = _Sheet(self.cell.spec.outline_w).hides(invert(T_c_w)[:3, 3], centers_w)
        reach = _normalized_reach(lens) * _MARK_FOV_FACTOR
        with np.errstate(divide="ignore", invalid="ignore"):
            near_fov = np.all(np.abs(centers_c[:, :2] / depth[:, None]) <= reach + (radii / depth)[:, None], axis=1)
        # the whole rim in front of the camera, not behind the sheet, about the image: worth a look at its rim
        candidates = (depth > radii) & ~hidden & near_fov
        draw: list[HoleSpec] = []
        truth: dict[str, MarkTruth] = {}
        for k, mark in enumerate(marks):
            rendered = in_view = False
            if candidates[k]:
                hole = HoleSpec(center_w=centers_w[k], radius_mm=float(radii[k]),
                                normal_w=R @ np.asarray(mark.normal_cf, dtype=float).reshape(3))
                rim = lens.project(_rim_w(hole) @ T_c_w[:3, :3].T + T_c_w[:3, 3])
                lo, hi = rim.min(axis=0), rim.max(axis=0)
                rendered = bool(hi[0] >= -0.5 and hi[1] >= -0.5 and lo[0] <= lens.width - 0.5
                                and lo[1] <= lens.height - 0.5)
                in_view = rendered and bool(np.all(lens.in_image(rim)))
                if rendered:
                    draw.append(hole)
            truth[mark.name] = MarkTruth(mark.name, centers_px[k].copy(), float(depth[k]), bool(hidden[k]), rendered,
                                         in_view)
        return draw, truth

    def _render_scene(self, scene: SimScene, failure: str | None) -> RenderedTarget | None:
        """The plate held in view, else the nearest calibration target in view; None: neither (the part shows)."""
        cell, cam = self.cell, self.cell.camera
        f = self._exposure_factor(failure) / (self.render.exposure or 1.0)
        t = self.target_render
        settings = replace(t, board_grey=min(255.0, t.board_grey * f), mark_grey=min(255.0, t.mark_grey * f),
                           background_grey=min(255.0, t.background_grey * f))
        if scene.T_c_plate is not None:
            plate = scene.plate
            return render_target(cam, scene.T_c_plate, plate.points(), plate.radius_mm, self.rng, settings)
        marks = cell.target_marks
        z0 = float(marks.centers_t[0, 2])  # the renderer wants the marks on the plane z = 0 of the frame it is given
        centers = marks.centers_t - np.array([0.0, 0.0, z0])
        T_c_cf = invert(cell.actual_camera_pose())
        best: tuple[float, int, np.ndarray] | None = None
        for i, T_cf_t in scene.targets.items():
            T_c_t = compose(T_c_cf, T_cf_t, make_T(np.eye(3), np.array([0.0, 0.0, z0])))
            centre_c = transform_points(T_c_t, centers.mean(axis=0).reshape(1, 3))
            if centre_c[0, 2] <= 0 or not bool(cam.in_image(cam.project(centre_c))[0]):
                continue
            if best is None or centre_c[0, 2] < best[0]:
                best = (float(centre_c[0, 2]), i, T_c_t)
        if best is None:
            return None
        _, i, T_c_t = best
        outline = np.vstack([centers, cell.spec.targets[i].points_t - np.array([0.0, 0.0, z0])]
                            if i < len(cell.spec.targets) else [centers])
        lo, hi = outline[:, :2].min(axis=0) - 2.5 * marks.radius_mm, outline[:, :2].max(axis=0) + 2.5 * marks.radius_mm
        board = np.array([[lo[0], lo[1], 0.0], [hi[0], lo[1], 0.0], [hi[0], hi[1], 0.0], [lo[0], hi[1], 0.0]])
        return render_target(cam, T_c_t, centers, marks.radius_mm, self.rng, settings, board_t=board)

    def _exposure_factor(self, failure: str | None) -> float:
        if failure == "black":
            return 0.0
        exposure_us = self.settings.exposure_us or self.cell.spec.exposure_us_nominal
        gain = 10.0 ** ((self.settings.gain_db or 0.0) / 20.0)
        return exposure_us / self.cell.spec.exposure_us_nominal * gain * self.render.exposure

    def _require_open(self) -> None:
        if not self._open:
            raise DeviceDisconnected("sim camera: not open")


def _serial(fault: object) -> int | None:
    """The serial number of a ``camera_fault`` entry, None when there is none (or it is malformed)."""
    if isinstance(fault, dict) and isinstance(fault.get("serial"), int):
        return int(fault["serial"])
    return None


class _Sheet:
    """The part's sheet as its outline polygon (in the part frame W) for the line-of-sight test; no outline: none."""

    def __init__(self, outline_w: np.ndarray | None) -> None:
        self.polygon: np.ndarray | None = None
        if outline_w is None:
            return
        corners = np.asarray(outline_w, dtype=float).reshape(-1, 3)
        self.origin = corners.mean(axis=0)
        _, _, vt = np.linalg.svd(corners - self.origin)
        self.normal, self.basis = vt[2], vt[:2].T  # the outline's plane (best fit) and a basis (3, 2) in it
        self.polygon = (corners - self.origin) @ self.basis  # (m, 2)
        self.edges_to = np.roll(self.polygon, -1, axis=0)  # each edge's other end

    def hides(self, eye_w: np.ndarray, points_w: np.ndarray) -> np.ndarray:
        """(n,) bool: the segment from ``eye_w`` (3,) to each of ``points_w`` (n, 3) crosses the outline's plane
        inside the outline (the even-odd rule)."""
        points_w = np.asarray(points_w, dtype=float).reshape(-1, 3)
        out = np.zeros(len(points_w), dtype=bool)
        if self.polygon is None:
            return out
        d0 = float(self.normal @ (eye_w - self.origin))
        d1 = (points_w - self.origin) @ self.normal
        crossing = np.flatnonzero(d0 * d1 < 0.0)  # else both on one side (or one on the plane): not between them
        if not len(crossing):
            return out
        lam = d0 / (d0 - d1[crossing])
        xy = (eye_w + lam[:, None] * (points_w[crossing] - eye_w) - self.origin) @ self.basis  # (k, 2) in the plane
        (x0, y0), (x1, y1) = self.polygon.T, self.edges_to.T
        x, y = xy[:, :1], xy[:, 1:]
        spans = (y0 > y) != (y1 > y)  # (k, m): the edges the line through the point parallel to the basis' x crosses
        with np.errstate(divide="ignore", invalid="ignore"):
            x_cross = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
        out[crossing] = np.count_nonzero(spans & (x < x_cross), axis=1) % 2 == 1
        return out


def _rim_w(hole: HoleSpec) -> np.ndarray:
    """The disc's rim at :data:`_MARK_RIM_POINTS` points (m, 3) in its frame."""
    n = np.asarray(hole.normal_w, dtype=float)
    n = n / np.linalg.norm(n)
    helper = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(n, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    t = np.linspace(0.0, 2.0 * np.pi, _MARK_RIM_POINTS, endpoint=False)
    return hole.center_w + hole.radius_mm * (np.cos(t)[:, None] * e1 + np.sin(t)[:, None] * e2)


def _normalized_reach(lens: CameraModel) -> np.ndarray:
    """(2,) the largest |x|, |y| of the image's corners and edge midpoints in ideal normalised coordinates."""
    w, h = lens.width - 0.5, lens.height - 0.5
    border = np.array([[-0.5, -0.5], [w, -0.5], [w, h], [-0.5, h], [lens.cx, -0.5], [lens.cx, h], [-0.5, lens.cy],
                       [w, lens.cy]])
    return np.abs(lens.undistort_pixels(border)).max(axis=0)


def _first_in_image(cell: SimCell, T_c_w: np.ndarray, holes: list[HoleSpec]) -> tuple[float, float]:
    points_c = np.array([(T_c_w @ np.append(h.center_w, 1.0))[:3] for h in holes])
    px = cell.camera.project(points_c)
    inside = np.flatnonzero(cell.camera.in_image(px) & (points_c[:, 2] > 0))
    u, v = px[inside[0]] if len(inside) else (cell.camera.cx, cell.camera.cy)
    return float(u), float(v)
