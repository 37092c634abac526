"""The parts of a cell by job with their one deviation envelope, and simulated parts drawn inside it or just
beyond one axis of it, judged by the offset check (``tests/solver/test_envelope.py``,
``benchmarks/bench_envelope.py``).

A job is taken from the config's ``[[parts]]`` (``CellConfig.parts``, each through ``CellConfig.for_job``) when
the config has them; the older single-part form gives job 1. A cell with one part gets the hood of issue 19 as
job 2, built here from the issue's description (:func:`issue_hood`: 1.5 m x 1.0 m, 6 featured holes, a crowned
sheet), with an envelope of its own: other per-axis limits, totals below the norms and its point off the holes'
centroid.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from monoguide.daemon.config import load_cell_config
from monoguide.daemon.config._service import ChecksConfig
from monoguide.solver import frames
from monoguide.solver.envelope import AXES, DeviationEnvelope, deviation_about, deviation_transform, draw_deviation
from monoguide.solver.errors import OffsetOutOfEnvelope
from monoguide.solver.offset import check_envelope, describe_displacement

SIM_CELL = Path(__file__).parents[2] / "config" / "sim-cell.toml"
HOOD_POINTS_W = np.array([[0.0, 0.0, 0.0], [750.0, -20.0, 38.0], [1500.0, 0.0, 0.0],
                          [0.0, 1000.0, 0.0], [750.0, 1020.0, 38.0], [1500.0, 1000.0, 0.0]])
HOOD_ENVELOPE = DeviationEnvelope((40.0, 30.0, 20.0), (3.0, 2.0, 4.0), (750.0, 500.0, 0.0), 45.0, 4.5)
HOOD_T_CF_W0 = frames.make_T(frames.rotvec_to_matrix(np.radians([0.0, 0.0, 90.0])), [3200.0, -400.0, 820.0])
# The six limits in the order of a draw's components: the rotation vector about x, y, z, then the shift.
COMPONENTS = tuple(f"rotation about {a}" for a in AXES) + tuple(f"shift along {a}" for a in AXES)


@dataclass(frozen=True)
class EnvelopeJob:
    """One part type: its job, name, holes (n, 3), grasp point (3,), reference ``T_cf_w0`` (4, 4), its first
    camera pose ``T_cf_s1`` (4, 4; SF1, the frame the cycle describes the displacement in) and envelope."""

    job: int
    name: str
    points_w: np.ndarray
    grasp_point_w: np.ndarray
    T_cf_w0: np.ndarray
    T_cf_s1: np.ndarray
    envelope: DeviationEnvelope


def envelope_jobs(config_path: Path = SIM_CELL) -> list[EnvelopeJob]:
    """The cell's parts by job (the hood added as job 2 to a cell of one part)."""
    cfg = load_cell_config(config_path)
    checks = cfg.checks or ChecksConfig()
    jobs = []
    for job in getattr(cfg, "jobs", (1,)):
        view = cfg.for_job(job) if hasattr(cfg, "for_job") else cfg
        planned = view.layout.envelope if view.layout is not None else None
        points = np.asarray(view.part.points_w, dtype=float)
        grasp = points.mean(axis=0) if view.part.grasp_point_w is None else np.asarray(view.part.grasp_point_w)
        jobs.append(EnvelopeJob(job, getattr(view, "part_name", "roof"), points, grasp, view.reference.T_cf_w0,
                                view.measuring_poses[0].T_cf_si, checks.envelope(planned).at(points)))
    return jobs if len(jobs) > 1 else [*jobs, issue_hood()]


def issue_hood(job: int = 2) -> EnvelopeJob:
    """The hood of issue 19 as built here, with its own envelope (totals below the norms, its point off the
    holes' centroid), its grasp point off both; SF1 a camera 650 mm above its centroid, looking down."""
    above = frames.make_T(np.diag([1.0, -1.0, -1.0]), HOOD_POINTS_W.mean(axis=0) + np.array([0.0, 0.0, 650.0]))
    return EnvelopeJob(job, "hood (issue 19, built here)", HOOD_POINTS_W, np.array([400.0, 500.0, 20.0]),
                       HOOD_T_CF_W0, HOOD_T_CF_W0 @ above, HOOD_ENVELOPE.at(HOOD_POINTS_W))


def inside_parts(job: EnvelopeJob, n: int, seed: int) -> list[np.ndarray]:
    """``T_w0_w`` of ``n`` parts drawn inside the job's envelope (seeded), as the simulated part supply draws."""
    rng = np.random.default_rng(seed)
    return [draw_deviation(rng, job.envelope, job.points_w) for _ in range(n)]


def beyond_one_axis(job: EnvelopeJob, T_w0_w: np.ndarray, component: int, sign: float,
                    factor: float = 1.01) -> np.ndarray:
    """The part ``T_w0_w`` with one component (index into :data:`COMPONENTS`) set to ``sign * factor`` times
    its per-axis limit, the others kept."""
    about = job.envelope.about(job.points_w)
    rotation_deg, shift_mm = deviation_about(T_w0_w, about)
    six = np.concatenate([rotation_deg, shift_mm])
    six[component] = sign * factor * (job.envelope.rotation_deg + job.envelope.translation_mm)[component]
    return deviation_transform(np.radians(six[:3]), six[3:], about)


def refusal(job: EnvelopeJob, T_w0_w: np.ndarray) -> str | None:
    """The offset check's refusal of the part ``T_w0_w`` as the cycle meets it (the pose in SF1 against the
    reference in SF1), or None when it passes."""
    T_s1_cf = frames.invert(job.T_cf_s1)
    T_s1_w0 = T_s1_cf @ job.T_cf_w0
    d = describe_displacement(T_s1_w0 @ T_w0_w, T_s1_w0, job.grasp_point_w, job.envelope.about(job.points_w))
    try:
        check_envelope(d, job.envelope)
    except OffsetOutOfEnvelope as error:
        return error.message
    return None


def names_component(message: str, component: int) -> bool:
    """Does a refusal name this component's axis (``along x`` for a shift, ``about x`` for a rotation)?"""
    axis = AXES[component % 3]
    return (f"about {axis} of" in message) if component < 3 else (f"along {axis} of" in message)
