"""Write ``config/sim-cell.toml``, the simulated paper roof cell (and its second part type, a hood), with explicit
matrices.

``python -m monoguide.drivers.sim.make_cell_config [--marks] [OUT.toml]`` (stdout without an argument).
The cell is the paper's (Sec. 5.1-5.2): Table 1 points, Table 2 intrinsics, the calibrated ``T_cf_w0``
and ``T_b_cf``. The four measuring poses are planned, not copied: ``solver.planning.plan_layout`` for
the constraints of the file's ``[layout]`` (:data:`LAYOUT`) over the paper's deviation envelope, +-50 mm
and +-5 deg on every axis, which is also the range the simulated parts are drawn from
(``[sim.deviation]``); ``T_cf_si = T_cf_w0 @ T_w0_si``. ``monoguide plan --layout`` on the written file
plans the same poses. The simulated robot's taught flange poses follow from them
(``SimCell.T_b_f_taught = inv(T_cf_b) T_cf_si inv(T_f_c)``). A real cell writes its taught and
calibrated poses into the same keys.

The cell's second part type (job 2) is a 1.5 m x 1.0 m hood with 6 featured holes (:data:`HOOD_POINTS_W`), lying
where the roof lies (its holes' centroid on the roof's), seen from 650 mm, 25 deg off its normal, by 3 measuring
poses with 2 holes each (:func:`hood_poses`), so that the cell also exercises views of several holes. They are not
planned (the planner plans one hole per view) but assessed (``assess_layout``) over the same envelope and
constraints.

``--marks`` writes the same cell with fixed reference marks (``config/sim-cell-marks.toml``): :data:`MARKS_PER_VIEW`
dark circles of :data:`MARK_DIAMETER_MM` on the fixture :data:`MARK_BELOW_MM` under the part's plane, about
:data:`MARK_DISTANCE_MM` from each roof view's hole on the side away from the part
(``solver.marks_layout.place_marks``), twice the holes' diameter so that the hole finder never takes one for the
other. The planner's check (``solver.planning.marks``, :func:`check_cell_marks`) must pass on them, or nothing is
written: each mark in its view's image, apart from the others, and never behind the roof anywhere in its envelope.
At 200 mm from the hole and 10 mm under the plane (the first placement) 8 of the 12 roof marks (and all 9 of the
hood's) failed it: the hole lies 40 mm inside the roof's edge, so a mark lay only 60-130 mm beyond it, and a roof
turned 5 deg about the holes' centroid (its corner sweeps ~105 mm) and shifted 50 mm covers that; 300 mm cleared
them but left room in the image only for three marks 26 mm apart on a line. 280 mm, 100 mm under the plane and
150 px inside the image keep every line of sight >= 31 mm outside the roof's edge (the radius and 5 mm: 15 mm) with
the marks spread (>= 145 mm apart, depth 620-720 mm). The hood's views (S5-S7) carry no marks: their holes lie
120 mm inside the hood's edge and their cameras look outwards across it, so a hood shifted, turned and tilted inside
the envelope (tilted 5 deg its sheet rises ~90 mm at the edge) covers every place below the part plane that their
images hold, but for a few clustered spots (:data:`MARKED_PARTS`).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import tomlkit
from tomlkit.items import Table

from monoguide.drivers.atomic_file import write_atomic
from monoguide.drivers.sim.hole_renderer import defocus_for_depth_of_field
from monoguide.drivers.toml_format import commented, inline_table, matrix, number, numbers
from monoguide.solver.calibration.target import default_target_marks
from monoguide.solver.camera import PAPER_CAMERA
from monoguide.solver.frames import compose, invert, make_T, orthonormalize, rotvec_to_matrix, transform_points
from monoguide.solver.marks_layout import MarkLayout, place_marks
from monoguide.solver.planning import (
    DeviationEnvelope,
    LayoutAssessment,
    LayoutConstraints,
    LayoutRequest,
    plan_layout,
)
from monoguide.solver.planning.marks import Mark, MarkedView, MarksVisibility, PartSheet, check_marks
from monoguide.solver.planning.request import assess_layout

# [layout]: what the measuring poses are planned for. The depth of field 450-900 mm is that of the 8.5 mm
# lens focused at 2 near far / (near + far) = 600 mm with its blur circle DEFOCUS_CIRCLE_PX wide at both ends
# (an entrance pupil of 1.5 mm, about f/5.6): [sim] focus_distance_mm and aperture_mm, so that the simulated
# camera blurs the holes as that lens would. Over the whole envelope the line of sight stays within 60 deg
# of the sheet's normal (a hole seen at half its width, at worst): the detector must hold that.
LAYOUT = LayoutConstraints(
    standoff_mm=(400.0, 1000.0),
    max_view_angle_deg=30.0,
    margin_px=100.0,
    depth_of_field_mm=(450.0, 900.0),
    max_view_angle_envelope_deg=60.0,
)
ENVELOPE = DeviationEnvelope(translation_mm=(50.0, 50.0, 50.0), rotation_deg=(5.0, 5.0, 5.0))
# The simulated parts are drawn within 99 % of the envelope: one drawn at its very edge is measured beyond it about
# half the time (the measurement's noise, ~0.1 mm), and refused (OFFSET_OUT_OF_ENVELOPE) as the check must
# (benchmarks/bench_envelope.py --measured: 0.4-0.6 % of parts drawn up to the limits).
SUPPLY_SHARE = 0.99
SIM_DEVIATION = DeviationEnvelope(translation_mm=tuple(SUPPLY_SHARE * v for v in ENVELOPE.translation_mm),
                                  rotation_deg=tuple(SUPPLY_SHARE * v for v in ENVELOPE.rotation_deg))
DEFOCUS_CIRCLE_PX = 2.0
SIGMA_PX = 0.1
REPEATABILITY_MM, REPEATABILITY_DEG = 0.05, 0.01
POINT_NAMES = ("P1", "P2", "P3", "P4")
HOOD_POINT_NAMES = ("H1", "H2", "H3", "H4", "H5", "H6")
HOOD_POINTS_W = np.array([[150.0, 120.0, 0.0], [400.0, 120.0, 0.0], [1380.0, 180.0, 0.0], [1380.0, 430.0, 0.0],
                          [600.0, 880.0, 0.0], [850.0, 880.0, 0.0]])
HOOD_VIEWS = ((0, 1), (2, 3), (4, 5))  # the holes each hood pose sees: pairs 250 mm apart
HOOD_STANDOFF_MM = 650.0
HOOD_TILT_DEG = 25.0  # off the hood's normal, like the roof's views (a target seen square on calibrates badly)
HOOD_HOLE_RADIUS_MM = 4.0
POINTS_W = np.array([[0.0, 0.0, 0.0], [1218.078, 0.0, 0.0], [1218.028, 2058.764, 0.0], [-1.017, 2059.039, -2.677]])
# the parts' outer edges in their frames: the roof's holes sit 40 mm in from its edges, the hood is 1.5 m x 1.0 m
ROOF_OUTLINE_W = np.array([[-40.0, -40.0, 0.0], [1258.0, -40.0, 0.0], [1258.0, 2099.0, 0.0], [-40.0, 2099.0, 0.0]])
HOOD_OUTLINE_W = np.array([[0.0, 0.0, 0.0], [1500.0, 0.0, 0.0], [1500.0, 1000.0, 0.0], [0.0, 1000.0, 0.0]])
MARKS_PER_VIEW = 3
MARK_DIAMETER_MM = 20.0
# where the roof views' marks go (docs/planning.md, Fixed marks): 280 mm from the hole, 100 mm under the part plane
# (the cameras look inwards from beyond the roof's corners, so a deeper mark's line of sight cuts the sheet's plane
# farther out), centres 150 px inside the image (room for a spread triangle; the circles keep >= 100 px)
MARK_DISTANCE_MM = 280.0
MARK_BELOW_MM = 100.0
MARK_MARGIN_PX = 150.0
MARKED_PARTS = ("roof",)  # whose views carry marks: none of the hood's views has room for marks it cannot cover
T_CF_W0_PAPER = np.array([
    [-0.9998, -0.0131, -0.0120, -1381.259],
    [0.0129, -0.9999, 0.0085, -152.268],
    [-0.0121, 0.0084, 0.9999, 383.642],
    [0.0, 0.0, 0.0, 1.0],
])
# As printed in Sec. 5.2 the rotation part of T_b_cf is a reflection (det -1); with the sign of R[1, 1]
# turned (a 178 deg turn about z, base facing the cell origin) it is a rotation. We use that reading.
T_B_CF_PAPER = np.array([
    [-0.9995, -0.0302, -0.0008, 325.252],
    [0.0302, -0.9995, -0.0005, 298.027],
    [0.0008, 0.0005, 0.9999, 28.037],
    [0.0, 0.0, 0.0, 1.0],
])
# The simulated camera's true mounting on the flange: 180 mm out along the tool axis, a little off-centre
# and turned, so that a wrong hand-eye assumption would show.
T_F_C_SIM = make_T(rotvec_to_matrix(np.radians([0.4, -0.3, 90.0])), np.array([62.0, -35.0, 180.0]))
# The tracker stands 3.5 m from the cell origin, turned 35 deg, on a 1.2 m stand.
T_CF_TRACKER_SIM = make_T(rotvec_to_matrix(np.radians([0.0, 0.0, 35.0])), np.array([2500.0, -2400.0, 1200.0]))
TARGET_POINTS_T = np.array([[0.0, 0.0, 0.0], [300.0, 0.0, 0.0], [300.0, 200.0, 0.0], [0.0, 200.0, 0.0]])
# the SMR nests that define the cell frame, nominal in CF: [cell_frame] (what calibrate measures) and
# [sim.benchmarks] (where the simulated nests are) hold the same
BENCHMARKS = {"B1": (0.0, 0.0, 0.0), "B2": (1500.0, 0.0, 0.0), "B3": (0.0, 1200.0, 0.0)}
# default_target_marks(): 13 x 9 marks at 20 mm, radius 4 mm, from (30, 20) mm
TARGET_MARKS = {"cols": 13, "rows": 9, "pitch_mm": 20.0, "radius_mm": 4.0, "origin_t": (30.0, 20.0, 0.0)}


def layout_request() -> LayoutRequest:
    """What the measuring poses are planned for: the request ``monoguide plan --layout`` reads from the
    written file (``[part]``, ``[camera.intrinsics]``, ``[layout]``)."""
    return LayoutRequest(
        camera=PAPER_CAMERA,
        points_w=POINTS_W,
        envelope=ENVELOPE,
        constraints=LAYOUT,
        sigma_px=SIGMA_PX,
        repeatability_mm=REPEATABILITY_MM,
        repeatability_deg=REPEATABILITY_DEG,
        point_names=POINT_NAMES,
        T_f_c=T_F_C_SIM,  # the repeatability acts at the flange, where the camera sits ([camera] T_f_c)
    )


def paper_cell_poses() -> dict[str, object]:
    """The matrices of the simulated roof cell: reference, robot base, measuring poses, targets, and the
    plan (:class:`~monoguide.solver.planning.LayoutAssessment`) the measuring poses come from."""
    T_cf_w0 = _exact(T_CF_W0_PAPER)
    T_cf_b = invert(_exact(T_B_CF_PAPER))
    plan = plan_layout(layout_request())
    T_cf_s = [compose(T_cf_w0, T) for T in plan.T_w0_si]
    T_cf_t = _target_poses(T_cf_w0, T_cf_s, plan.depth_mm.mean(axis=1))
    return {"T_cf_w0": T_cf_w0, "T_cf_b": T_cf_b, "T_cf_s": T_cf_s, "T_cf_t": T_cf_t, "plan": plan}


def hood_poses(T_cf_w0_roof: np.ndarray) -> dict[str, object]:
    """The hood's reference (its holes' centroid where the roof's is), its three measuring poses (each looking at
    the middle of a pair of holes from :data:`HOOD_STANDOFF_MM`, tilted :data:`HOOD_TILT_DEG` about the pair's
    line so that both holes stay at one depth, the pair along the image's long side) and their assessment."""
    shift = POINTS_W.mean(axis=0) - HOOD_POINTS_W.mean(axis=0)
    shift[2] = 0.0
    T_cf_w0 = compose(T_cf_w0_roof, make_T(np.eye(3), shift))
    up, tilt = np.array([0.0, 0.0, 1.0]), np.radians(HOOD_TILT_DEG)
    T_w0_s = []
    for a, b in HOOD_VIEWS:
        along = HOOD_POINTS_W[b] - HOOD_POINTS_W[a]
        along /= np.linalg.norm(along)
        aside = np.cross(up, along)
        middle = (HOOD_POINTS_W[a] + HOOD_POINTS_W[b]) / 2
        centre = middle + HOOD_STANDOFF_MM * (np.cos(tilt) * up + np.sin(tilt) * aside)
        z = (middle - centre) / np.linalg.norm(middle - centre)
        x = along - (along @ z) * z
        x /= np.linalg.norm(x)
        T_w0_s.append(make_T(np.column_stack([x, np.cross(z, x), z]), centre))
    request = LayoutRequest(camera=PAPER_CAMERA, points_w=HOOD_POINTS_W, envelope=ENVELOPE, constraints=LAYOUT,
                            sigma_px=SIGMA_PX, repeatability_mm=REPEATABILITY_MM, repeatability_deg=REPEATABILITY_DEG,
                            point_names=HOOD_POINT_NAMES, T_f_c=T_F_C_SIM)
    observed = [(v, j) for v, pair in enumerate(HOOD_VIEWS) for j in pair]
    assessment = assess_layout(request, T_w0_s, observed)
    assert assessment.margin_px_min >= LAYOUT.margin_px and assessment.sigmas is not None, "the hood's views fail"
    return {"T_cf_w0": T_cf_w0, "T_cf_s": [compose(T_cf_w0, T) for T in T_w0_s], "plan": assessment}


def _target_poses(T_cf_w0: np.ndarray, T_cf_s: list[np.ndarray], depths: np.ndarray) -> list[np.ndarray]:
    """One calibration target per measuring pose, centred on the optical axis at its holes' depth, lying flat
    like the part (the paper's Fig. 2)."""
    centre_t = TARGET_POINTS_T.mean(axis=0)
    R = T_cf_w0[:3, :3]
    return [make_T(R, (T @ np.array([0.0, 0.0, depth, 1.0]))[:3] - R @ centre_t)
            for T, depth in zip(T_cf_s, depths, strict=True)]


def cell_marks(m: dict[str, object], hood: dict[str, object]) -> tuple[MarkLayout | None, MarkLayout | None]:
    """The fixed marks of the roof's views and of the hood's (``[[reference_marks]]``), each view's about its
    hole(s) as the reference part lies; None for a part type whose views carry none (:data:`MARKED_PARTS`)."""
    out: list[MarkLayout | None] = []
    for name, T_cf_w0, T_cf_s, points, views, first in (
            ("roof", m["T_cf_w0"], m["T_cf_s"], POINTS_W, tuple((i,) for i in range(len(POINTS_W))), 1),
            ("hood", hood["T_cf_w0"], hood["T_cf_s"], HOOD_POINTS_W, HOOD_VIEWS, len(POINTS_W) + 1)):
        if name not in MARKED_PARTS:
            out.append(None)
            continue
        holes_cf = np.array([transform_points(T_cf_w0, points[list(v)]).mean(axis=0) for v in views])
        out.append(place_marks(PAPER_CAMERA, T_cf_s, holes_cf, count=MARKS_PER_VIEW, distance_mm=MARK_DISTANCE_MM,
                               below_mm=MARK_BELOW_MM, margin_px=MARK_MARGIN_PX, normal_cf=T_cf_w0[:3, 2],
                               view_names=[f"S{first + k}" for k in range(len(views))]))
    return out[0], out[1]


def check_cell_marks(m: dict[str, object], hood: dict[str, object],
                     layouts: tuple[MarkLayout | None, MarkLayout | None]) -> MarksVisibility:
    """The planner's check of the cell's marks (``solver.planning.marks``), as ``monoguide plan`` makes it on the
    written file: each view's marks in its image :data:`LAYOUT` ``margin_px`` inside, apart, and never hidden by its
    part (the roof's views by the roof, the hood's by the hood) anywhere in :data:`ENVELOPE`."""
    normal = m["T_cf_w0"][:3, 2]
    marks: list[Mark] = []
    views: list[MarkedView] = []
    parts = (PartSheet("roof", m["T_cf_w0"], POINTS_W, ENVELOPE.at(POINTS_W), ROOF_OUTLINE_W),
             PartSheet("hood", hood["T_cf_w0"], HOOD_POINTS_W, ENVELOPE.at(HOOD_POINTS_W), HOOD_OUTLINE_W))
    n_views = 0
    for part, (layout, T_cf_s) in enumerate(zip(layouts, (m["T_cf_s"], hood["T_cf_s"]), strict=True)):
        if layout is None:
            n_views += len(T_cf_s)
            continue
        first = len(marks)
        marks += [Mark(k.name, k.position_cf, MARK_DIAMETER_MM / 2.0, normal) for k in layout.marks]
        for v, T in enumerate(T_cf_s):
            n_views += 1
            views.append(MarkedView(f"S{n_views}", T, tuple(first + j for j in layout.marks_per_view[v]), (part,),
                                    LAYOUT.margin_px))
    return check_marks(PAPER_CAMERA, views, marks, parts)


def cell_config_toml(marks: bool = False) -> str:
    """The text of ``config/sim-cell.toml`` (``marks``: of ``config/sim-cell-marks.toml``)."""
    m = paper_cell_poses()
    hood = hood_poses(m["T_cf_w0"])
    hood_plan: LayoutAssessment = hood["plan"]
    hood_targets = _target_poses(hood["T_cf_w0"], hood["T_cf_s"], np.full(len(HOOD_VIEWS), HOOD_STANDOFF_MM))
    plan: LayoutAssessment = m["plan"]
    focus_mm, aperture_mm = defocus_for_depth_of_field(PAPER_CAMERA.fx, *LAYOUT.depth_of_field_mm, DEFOCUS_CIRCLE_PX)
    s, r = plan.sigmas, plan.sigmas_with_repeatability
    layouts = cell_marks(m, hood) if marks else None
    clearance = ""
    if layouts is not None:
        check = check_cell_marks(m, hood, layouts)
        assert check.ok, f"the generated marks fail the planner's check: {check.error()}"
        clearance = f"{min(x.clearance_mm for x in check.results if x.clearance_mm is not None):.0f}"
    doc = tomlkit.document()
    for line in (
        "The simulated paper roof cell (Sec. 5 of the paper). Generated by",
        "  python -m monoguide.drivers.sim.make_cell_config config/sim-cell.toml",
        "Measuring poses planned by `monoguide plan --layout` for [layout] over +-50 mm / +-5 deg on every axis:",
        f"predicted sigma {s.sigma_rot_deg:.4f} deg / {s.sigma_trans_mm:.3f} mm at the grasp point "
        f"({s.sigma_origin_mm:.3f} mm at the part origin) for {SIGMA_PX:g} px,",
        f"{r.sigma_rot_deg:.4f} deg / {r.sigma_trans_mm:.3f} mm with the robot's repeatability (at the flange); "
        f"every hole >= {plan.margin_px_min:.0f} px inside the image,",
        f"depth {plan.depth_mm_min:.0f}-{plan.depth_mm_max:.0f} mm.",
        f"Job 2, the hood: 3 poses of 2 holes each (assessed, not planned), predicted sigma "
        f"{hood_plan.sigmas_with_repeatability.sigma_trans_mm:.3f} mm at the grasp point",
        f"with the repeatability; every hole >= {hood_plan.margin_px_min:.0f} px inside the image.",
        *([f"With {MARKS_PER_VIEW} fixed reference marks per roof measuring pose (S1-S4), {MARK_DIAMETER_MM:g} mm dark "
            f"circles on the fixture {MARK_BELOW_MM:g} mm",
            f"below the roof's plane about {MARK_DISTANCE_MM:g} mm from its hole, surveyed by the tracker "
            "([[reference_marks]], docs/cycle-marks.md);",
            f"their lines of sight pass >= {clearance} mm outside the roof's edge wherever it lies in its envelope "
            "(`monoguide plan`);",
            "the hood's poses have none (no room in their images for marks a hood in its envelope cannot cover):",
            "  python -m monoguide.drivers.sim.make_cell_config --marks config/sim-cell-marks.toml"] if marks else []),
        "Edit the generator, not this file.",
    ):
        doc.add(tomlkit.comment(line))
    doc.add(tomlkit.nl())
    doc["cell"] = _table({"name": "paper roof cell with reference marks (simulated)" if marks
                          else "paper roof cell (simulated)"})
    camera = _table({"backend": "sim", "pixel_format": "Mono8", "exposure_us": 8000.0, "grab_timeout_s": 2.0,
                     "T_f_c": matrix(T_F_C_SIM)})
    camera["intrinsics"] = _table(PAPER_CAMERA.as_dict(), "Table 2")
    doc["camera"] = camera
    doc["reference"] = _table({"T_cf_b": matrix(m["T_cf_b"])},
                              "inv(T_b_cf) of Sec. 5.2 (R[1, 1] sign-corrected), orthonormalised: the robot base")
    doc["layout"] = _layout_table()
    if layouts is not None:
        reference_marks = tomlkit.aot()
        for layout in (lay for lay in layouts if lay is not None):
            for mark in layout.marks:
                reference_marks.append(_table({"name": mark.name, "position_cf": numbers(mark.position_cf, 3),
                                               "diameter_mm": MARK_DIAMETER_MM,
                                               "normal_cf": numbers(m["T_cf_w0"][:3, 2], 6)}))
        doc["reference_marks"] = reference_marks
    poses = tomlkit.aot()
    for i, T in enumerate(m["T_cf_s"]):
        u, v = plan.pixels[i]
        name = commented(tomlkit.item(f"S{i + 1}"), f"roof {POINT_NAMES[i]} at {plan.standoff_mm[i]:.1f} mm, line of "
                         f"sight {plan.view_angle_deg[i]:.1f} deg off the normal, imaged at ({u:.1f}, {v:.1f}) px")
        poses.append(_table({"name": name, "T_cf_si": matrix(T), **_pose_marks(layouts, 0, i)}))
    for k, T in enumerate(hood["T_cf_s"]):
        holes = " and ".join(HOOD_POINT_NAMES[j] for j in HOOD_VIEWS[k])
        note = f"hood {holes}, from {HOOD_STANDOFF_MM:g} mm, {HOOD_TILT_DEG:g} deg off its normal"
        poses.append(_table({"name": commented(tomlkit.item(f"S{len(m['T_cf_s']) + k + 1}"), note),
                             "T_cf_si": matrix(T), **_pose_marks(layouts, 1, k)}))
    doc["measuring_poses"] = poses
    parts = tomlkit.aot()
    parts.append(_table({
        "job": 1, "name": "roof", "hole_radius_mm": 5.0, "point_names": list(POINT_NAMES),
        "points_w": commented(matrix(POINTS_W, 6, multiline=False), "Table 1, the roof's featured holes in WF"),
        "outline_w": commented(matrix(ROOF_OUTLINE_W, 1, multiline=False), "its outer edge"),
        "T_cf_w0": commented(matrix(m["T_cf_w0"]), "T_cf_w0 of Sec. 5.2, orthonormalised"),
        "measuring_poses": inline_table({f"S{i + 1}": [POINT_NAMES[i]] for i in range(len(m["T_cf_s"]))}),
    }))
    first_hood = len(m["T_cf_s"]) + 1
    parts.append(_table({
        "job": 2, "name": "hood", "hole_radius_mm": HOOD_HOLE_RADIUS_MM, "point_names": list(HOOD_POINT_NAMES),
        "points_w": matrix(HOOD_POINTS_W, 1, multiline=False),
        "outline_w": matrix(HOOD_OUTLINE_W, 1, multiline=False),
        "T_cf_w0": commented(matrix(hood["T_cf_w0"]), "its holes' centroid where the roof's is"),
        "measuring_poses": inline_table({f"S{first_hood + k}": [HOOD_POINT_NAMES[j] for j in pair]
                                         for k, pair in enumerate(HOOD_VIEWS)}),
    }))
    doc["parts"] = parts
    doc["cell_frame"], doc["calibration_target"] = _calibration_tables()
    doc["tracker"] = _table({
        "backend": commented(tomlkit.item("sim"), "the port is read from the state file that `monoguide sim-cell` "
                                                  "writes"),
        "baud": 115200, "timeout_s": 2.0})
    doc["robot"] = _table({
        "backend": commented(tomlkit.item("sim-ur"), "or \"sim-kuka\"; a real cell: \"ur\" or \"kuka\" with the "
                                                     "controller's host"),
        "host": commented(tomlkit.item("127.0.0.1"), "where the simulated controller listens (sim-cell writes it into "
                                                     "its state file)"),
        "port": 30004, "connect_timeout_s": 3.0, "move_timeout_s": 10.0, "ack_timeout_s": 2.0,
        "pose_tolerance_mm": 1.0, "pose_tolerance_deg": 0.1, "sim_move_time_s": 0.5}, "docs/robot-interface.md")
    doc["plc"] = _table({
        "host": commented(tomlkit.item("127.0.0.1"), "the simulated PLC listens here (`sim-cell --no-plc`: another "
                                                     "server can)"),
        "port": commented(tomlkit.item(5020), "a real PLC: 502"),
        "unit": 1, "base": 0, "word_order": "big", "heartbeat_timeout_s": 2.0}, "docs/plc-interface.md")
    doc["checks"] = _table({"max_rms_px": 1.5}, "the chi-square test is the statistical check; the RMS bound, on top "
                           "of it, sits above what the robot's 0.01 deg repeatability puts into a view (f 0.01 deg = "
                           "0.4 px; docs/cycle.md)")
    sim = _table({
        "seed": 20240601, "repeatability_mm": 0.05, "repeatability_deg": 0.01, "tracker_noise_mm": 0.025,
        "exposure_us_nominal": 8000.0, "focus_distance_mm": number(focus_mm, 1),
        "aperture_mm": commented(number(aperture_mm, 4), f"blur circle {DEFOCUS_CIRCLE_PX:g} px at the depth of "
                                                         "field's ends"),
        "tool_smr_f": [0.0, 0.0, 250.0], "T_f_c": matrix(T_F_C_SIM), "T_cf_tracker": matrix(T_CF_TRACKER_SIM)})
    sim["deviation"] = _table({"translation_mm": numbers(SIM_DEVIATION.translation_mm, 2),
                               "rotation_deg": numbers(SIM_DEVIATION.rotation_deg, 2)},
                              f"+- per axis, about the holes' centroid: {SUPPLY_SHARE * 100:g} % of the envelope "
                              "(the measurement's noise at its very edge)")
    sim["benchmarks"] = _table({name: numbers(xyz, 1) for name, xyz in BENCHMARKS.items()},
                               "the three SMR nests that define the cell frame (where they truly are: [cell_frame])")
    targets = tomlkit.aot()
    for i, T in enumerate([*m["T_cf_t"], *hood_targets]):
        targets.append(_table({"name": commented(tomlkit.item(f"T{i + 1}"), f"under measuring pose S{i + 1}"),
                               "T_cf_t": matrix(T), "points_t": matrix(TARGET_POINTS_T, 6, multiline=False)}))
    sim["targets"] = targets
    doc["sim"] = sim
    return doc.as_string()


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    marks = "--marks" in argv
    argv = [a for a in argv if a != "--marks"]
    text = cell_config_toml(marks)
    if argv:
        write_atomic(Path(argv[0]), text)
    else:
        sys.stdout.write(text)
    return 0


# --- private -----------------------------------------------------------------------------------


def _pose_marks(layouts: tuple[MarkLayout | None, MarkLayout | None] | None, part: int,
                view: int) -> dict[str, object]:
    """``marks = [...]`` of a measuring pose (nothing without marks)."""
    if layouts is None or layouts[part] is None:
        return {}
    layout = layouts[part]
    return {"marks": [layout.marks[j].name for j in layout.marks_per_view[view]]}


def _exact(T: np.ndarray) -> np.ndarray:
    out = T.copy()
    out[:3, :3] = orthonormalize(T[:3, :3])
    return out


def _table(values: dict[str, object], comment: str | None = None) -> Table:
    """A table of ``values`` in their order (tomlkit items kept as they are), ``comment`` after its header."""
    table = tomlkit.table()
    for key, value in values.items():
        table[key] = value
    return commented(table, comment) if comment else table


def _calibration_tables() -> tuple[Table, Table]:
    """[cell_frame] and [calibration_target]: what `monoguide calibrate` measures the cell with."""
    m = TARGET_MARKS
    marks = default_target_marks()
    ox, oy, oz = m["origin_t"]
    pitch = m["pitch_mm"]
    expected = [[ox + c * pitch, oy + r * pitch, oz] for r in range(m["rows"]) for c in range(m["cols"])]
    assert np.allclose(marks.centers_t, expected) and marks.radius_mm == m["radius_mm"], "default_target_marks changed"
    benchmarks = inline_table({name: numbers(xyz, 1) for name, xyz in BENCHMARKS.items()})
    cell_frame = _table({"method": "best-fit", "benchmarks": benchmarks},
                        "the benchmark SMR nests that define CF, nominal (monoguide calibrate; docs/calibration.md)")
    target = _table({"nests_t": matrix(TARGET_POINTS_T, 1, multiline=False), "marks_cols": m["cols"],
                     "marks_rows": m["rows"], "marks_pitch_mm": number(m["pitch_mm"], 1),
                     "marks_radius_mm": number(m["radius_mm"], 1), "marks_origin_t": numbers(m["origin_t"], 1)},
                    "the simulated targets (SMR nests at the corners; default_target_marks())")
    return cell_frame, target


def _layout_table() -> Table:
    c = LAYOUT
    return _table({
        "standoff_mm": numbers(c.standoff_mm, 1),
        "max_view_angle_deg": number(c.max_view_angle_deg, 1),
        "max_view_angle_envelope_deg": number(c.max_view_angle_envelope_deg, 1),
        "margin_px": number(c.margin_px, 1),
        "depth_of_field_mm": commented(numbers(c.depth_of_field_mm, 1), "the lens focused at [sim] focus_distance_mm"),
        "sigma_px": SIGMA_PX,
        "repeatability_mm": REPEATABILITY_MM,
        "repeatability_deg": REPEATABILITY_DEG,
        "envelope_translation_mm": numbers(ENVELOPE.translation_mm, 1),
        "envelope_rotation_deg": numbers(ENVELOPE.rotation_deg, 1),
    }, "what the measuring poses are planned for (monoguide plan --layout; docs/planning.md)")


if __name__ == "__main__":
    sys.exit(main())
