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
from dataclasses import replace
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
from monoguide.solver.frames import compose, invert, make_T, transform_points

log = logging.getLogger(__name__)

FAILURES = ("timeout", "disconnect", "black", "occluded", "glare")
MAX_SIM_TIMEOUT_S = 0.2  # a simulated timeout waits at most this long before raising


class SimCamera:
    """:class:`~monoguide.drivers.camera.Camera` reading a :class:`SimCell`. ``last_view`` keeps the last
    rendering's ground truth (``centers_px`` in full-sensor pixels, ``in_view``)."""

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
        view = render_view(lens, T_c_w, holes, settings, self.rng)
        if failure == "occluded":
            # something (a cable, a gripper finger) lies over the hole: sheet-grey disc at the hole
            r = int(3.0 * cell.spec.hole_radius_mm * cell.camera.fx / max(float(T_c_w[2, 3]), 1.0)) + 8
            grey = int(np.clip(settings.sheet_grey * settings.exposure, 0, 255))
            for (u, v), seen in zip(view.centers_px, view.in_view, strict=True):
                if seen:
                    cv2.circle(view.image, (round(u), round(v)), r, grey, thickness=-1)
        return view

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


def _first_in_image(cell: SimCell, T_c_w: np.ndarray, holes: list[HoleSpec]) -> tuple[float, float]:
    points_c = np.array([(T_c_w @ np.append(h.center_w, 1.0))[:3] for h in holes])
    px = cell.camera.project(points_c)
    inside = np.flatnonzero(cell.camera.in_image(px) & (points_c[:, 2] > 0))
    u, v = px[inside[0]] if len(inside) else (cell.camera.cx, cell.camera.cy)
    return float(u), float(v)
