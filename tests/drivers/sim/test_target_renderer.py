"""The calibration-target renderer (issue 12): exact coverage, the lens's distortion, seeded noise."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from monoguide.drivers.sim.target_renderer import TargetRenderSettings, look_at, render_target
from monoguide.solver.calibration.target import measure_mark
from monoguide.solver.camera import PAPER_CAMERA
from monoguide.solver.frames import invert
from monoguide.solver.holes import perspective_correction

PINHOLE = replace(PAPER_CAMERA, k1=0.0, k2=0.0, p1=0.0, p2=0.0)
CLEAN = TargetRenderSettings(blur_sigma_px=0.0, noise_sigma=0.0, supersample=8)


def test_a_disc_covers_exactly_its_area() -> None:
    """Fronto-parallel, pinhole, no blur or noise: the rendered darkness sums to the disc's area pi (f r / Z)^2."""
    Z, r = 600.0, 10.0
    centre = np.array([[0.0, 0.0, 0.0]])
    T_c_t = invert(look_at(np.array([0.0, 0.0, Z]), np.zeros(3), np.array([0.0, -1.0, 0.0])))
    T_c_t[:3, 3] += np.array([3.3, -1.7, 0.0])  # off the pixel grid
    img = render_target(PINHOLE, T_c_t, centre, r, np.random.default_rng(0), CLEAN,
                        board_t=np.array([[-50, -50, 0], [50, -50, 0], [50, 50, 0], [-50, 50, 0]], dtype=float))
    u, v = PINHOLE.project(T_c_t[:3, 3].reshape(1, 3))[0]
    box = img.image[int(v) - 40:int(v) + 41, int(u) - 40:int(u) + 41].astype(float)
    darkness = (CLEAN.board_grey - box) / (CLEAN.board_grey - CLEAN.mark_grey)
    r_px = PINHOLE.fx * r / Z  # fx and fy differ by 0.07 %: the area is pi r_x r_y
    area = math.pi * r_px * (PINHOLE.fy * r / Z)
    assert abs(darkness.sum() / area - 1.0) < 0.002  # 8-bit rounding and supersampling only


def test_centres_follow_the_lens_model_and_the_rendered_rims_agree() -> None:
    rng = np.random.default_rng(3)
    centers_t = np.array([[0.0, 0.0, 0.0], [150.0, 100.0, 0.0], [-180.0, -150.0, 0.0]])
    T_t_c = look_at(np.array([60.0, -250.0, 560.0]), np.array([0.0, 0.0, 0.0]))
    T_c_t = invert(T_t_c)
    view = render_target(PAPER_CAMERA, T_c_t, centers_t, 8.0, rng)
    expected = PAPER_CAMERA.project(centers_t @ T_c_t[:3, :3].T + T_c_t[:3, 3])
    assert np.allclose(view.centers_px, expected, atol=1e-9)
    assert view.in_view.all()
    for k, c in enumerate(centers_t):
        z = float((T_c_t @ np.append(c, 1.0))[2])
        found, _ = measure_mark(view.image, expected[k], 8.0 * PAPER_CAMERA.fx / z, 5.0, photometric=False)
        corrected = found - perspective_correction(PAPER_CAMERA, T_c_t, c, np.array([0.0, 0.0, 1.0]), 8.0)
        assert np.linalg.norm(corrected - expected[k]) < 0.05, k
    # the distortion is rendered, not ignored: the same marks through a pinhole land elsewhere
    pinhole = PINHOLE.project(centers_t @ T_c_t[:3, :3].T + T_c_t[:3, 3])
    assert np.max(np.linalg.norm(pinhole - expected, axis=1)) > 2.0  # 30 times the agreement above


def test_the_noise_is_seeded() -> None:
    T_c_t = invert(look_at(np.array([0.0, 0.0, 600.0]), np.zeros(3)))
    centres = np.array([[0.0, 0.0, 0.0], [40.0, 0.0, 0.0]])
    a = render_target(PAPER_CAMERA, T_c_t, centres, 6.0, np.random.default_rng(9)).image
    b = render_target(PAPER_CAMERA, T_c_t, centres, 6.0, np.random.default_rng(9)).image
    c = render_target(PAPER_CAMERA, T_c_t, centres, 6.0, np.random.default_rng(10)).image
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    assert a.shape == (PAPER_CAMERA.height, PAPER_CAMERA.width) and a.dtype == np.uint8
    # the noise is what was asked for (2 grey levels) where the board is flat
    patch = a[900:1000, 1400:1500].astype(float)
    assert 1.5 < patch.std() < 2.5
