"""The one envelope definition: the part supply's draw, the planner's transform and the offset check agree, at
its edges on every axis, for the roof of config/sim-cell.toml and a second part of another shape (the hood)."""

import numpy as np
import pytest
from helpers.envelope_jobs import (
    COMPONENTS,
    beyond_one_axis,
    envelope_jobs,
    inside_parts,
    issue_hood,
    names_component,
    refusal,
)

from monoguide.drivers.sim.cell import deviated_part
from monoguide.solver import frames
from monoguide.solver.envelope import DeviationEnvelope, deviation_about, deviation_transform, draw_deviation

CELL_JOBS = envelope_jobs()  # the config's parts by job (the hood built here while the config has one part)
HOOD = issue_hood(job=99)  # the hood with an envelope of its own: totals below the norms, its point off-centroid
JOBS = [*CELL_JOBS, HOOD]
SIGNS = (-1.0, 1.0)


def test_the_cell_has_two_parts_of_different_shapes():
    assert [j.job for j in CELL_JOBS][:2] == [1, 2]
    roof, hood = CELL_JOBS[0], CELL_JOBS[1]
    assert (len(roof.points_w), len(hood.points_w)) == (4, 6)


def test_a_draw_is_the_supplys_draw_of_today_when_the_totals_are_the_norms():
    """Ground truth: the simulated cell's own draw (``drivers.sim.cell.deviated_part``), the same seed."""
    points = CELL_JOBS[0].points_w
    envelope = DeviationEnvelope((50.0, 40.0, 5.0), (0.5, 1.0, 2.0)).at(points)
    for seed in range(20):
        T_cf_w0 = CELL_JOBS[0].T_cf_w0
        expected = deviated_part(np.random.default_rng(seed), T_cf_w0, points.mean(axis=0), (50.0, 40.0, 5.0),
                                 (0.5, 1.0, 2.0))
        drawn = T_cf_w0 @ draw_deviation(np.random.default_rng(seed), envelope, points)
        np.testing.assert_allclose(drawn, expected, atol=1e-9)


def test_the_displacement_about_the_point_is_the_drawn_rotation_and_shift():
    rng = np.random.default_rng(3)
    for _ in range(50):
        r_deg, t, about = rng.uniform(-20, 20, 3), rng.uniform(-300, 300, 3), rng.uniform(-2000, 2000, 3)
        rotation, shift = deviation_about(deviation_transform(np.radians(r_deg), t, about), about)
        np.testing.assert_allclose(rotation, r_deg, atol=1e-9)
        np.testing.assert_allclose(shift, t, atol=1e-9)
        # the point itself moves by t: T_w0_w a = a + t
        T = deviation_transform(np.radians(r_deg), t, about)
        np.testing.assert_allclose(frames.transform_points(T, about[None])[0], about + t, atol=1e-9)


@pytest.mark.parametrize("job", JOBS, ids=lambda j: f"job{j.job}")
@pytest.mark.parametrize("component", range(6), ids=COMPONENTS)
@pytest.mark.parametrize("sign", SIGNS, ids=("minus", "plus"))
def test_the_envelope_at_its_edge_on_every_axis(job, component, sign):
    """A part turned or shifted along one axis alone: just inside its limit passes, 1 % beyond it is refused
    naming that axis."""
    limit = (job.envelope.rotation_deg + job.envelope.translation_mm)[component]
    assert refusal(job, beyond_one_axis(job, np.eye(4), component, sign, factor=0.999)) is None
    message = refusal(job, beyond_one_axis(job, np.eye(4), component, sign, factor=1.01))
    assert message is not None and names_component(message, component), message
    assert f"±{limit:g}" in message


@pytest.mark.parametrize("job", JOBS, ids=lambda j: f"job{j.job}")
def test_seeded_parts_inside_pass_and_one_percent_beyond_one_axis_are_refused_naming_it(job):
    parts = inside_parts(job, 150, seed=19 + job.job)
    assert [refusal(job, T) for T in parts] == [None] * len(parts)
    for component in range(6):
        for sign in SIGNS:
            messages = [refusal(job, beyond_one_axis(job, T, component, sign)) for T in parts[:25]]
            assert all(m is not None and names_component(m, component) for m in messages), (component, messages)


def test_the_hoods_totals_cut_the_corners_of_its_box():
    """The hood's totals (45 mm, 4.5 deg) lie below the norms of its per-axis limits: a part inside every axis
    but beyond a total is refused in total, and the supply never draws one."""
    hood = HOOD
    assert hood.envelope.limit_mm < np.linalg.norm(hood.envelope.translation_mm)
    about = hood.envelope.about(hood.points_w)
    corner = deviation_transform(np.zeros(3), 0.99 * np.asarray(hood.envelope.translation_mm), about)
    assert "in total" in refusal(hood, corner)
    turned = deviation_transform(np.radians(0.99 * np.asarray(hood.envelope.rotation_deg)), np.zeros(3), about)
    assert "in total" in refusal(hood, turned)
    for T in inside_parts(hood, 300, seed=5):
        rotation, shift = deviation_about(T, about)
        assert np.linalg.norm(shift) <= 45.0 and np.linalg.norm(rotation) <= 4.5


def test_the_hoods_envelope_is_about_its_point_not_a_hole_nor_the_grasp_point():
    """Turned 3.9 deg about z in place about its envelope's point: inside, however far the holes move. The same
    turn about its corner hole P1 (the origin) moves the envelope's point (750, 500) by the lever, computed here
    by hand: (750 (cos - 1) - 500 sin, 750 sin + 500 (cos - 1)) = (-35.8, +49.9) mm, beyond ±30 mm along y."""
    hood = HOOD
    about = hood.envelope.about(hood.points_w)
    theta = np.radians(3.9)
    in_place = deviation_transform([0.0, 0.0, theta], np.zeros(3), about)
    assert refusal(hood, in_place) is None
    assert np.linalg.norm(frames.transform_points(in_place, hood.points_w[:1]) - hood.points_w[:1]) > 60.0
    about_p1 = deviation_transform([0.0, 0.0, theta], np.zeros(3), hood.points_w[0])
    expected = [750 * (np.cos(theta) - 1) - 500 * np.sin(theta), 750 * np.sin(theta) + 500 * (np.cos(theta) - 1), 0]
    np.testing.assert_allclose(deviation_about(about_p1, about)[1], expected, atol=1e-9)
    assert f"lies {expected[1]:+.2f} mm off along y" in refusal(hood, about_p1)
