"""A Mono12 frame saved by `monoguide probe camera --out F.png` carries its bit depth (an sBIT chunk), so
`monoguide detect F.png` finds the hole without --bit-depth; checked against the renderer's truth."""

import json
from dataclasses import replace

import cv2
import numpy as np
from PIL import Image
from typer.testing import CliRunner

from monoguide.daemon.cli import app
from monoguide.daemon.cli.probe import _significant_bits, png_with_significant_bits
from monoguide.drivers.sim.hole_renderer import HoleSpec, RenderSettings, render_view
from monoguide.solver import frames
from monoguide.solver.camera import PAPER_CAMERA

runner = CliRunner()
LOOK_DOWN = frames.make_T(np.diag([1.0, -1.0, -1.0]), np.array([0.0, 0.0, 650.0]))
CAMERA = replace(PAPER_CAMERA, width=320, height=240, cx=PAPER_CAMERA.cx - 1080, cy=PAPER_CAMERA.cy - 850)


def test_a_mono12_png_with_its_sbit_chunk_is_read_at_12_bits(tmp_path):
    view = render_view(CAMERA, LOOK_DOWN, [HoleSpec(np.array([1.0, 2.0, 0.0]), 6.0)], RenderSettings(),
                       np.random.default_rng(12))
    mono12 = (view.image.astype(np.uint16) << 4) | (view.image.astype(np.uint16) >> 4)  # 0..4095, Mono12
    plain = tmp_path / "plain.png"
    assert cv2.imwrite(str(plain), mono12)
    marked = tmp_path / "frame.png"
    marked.write_bytes(png_with_significant_bits(plain.read_bytes(), _significant_bits("Mono12")))

    with Image.open(marked) as check:  # a valid PNG (CRCs checked), the pixels unchanged
        check.load()
    np.testing.assert_array_equal(cv2.imread(str(marked), cv2.IMREAD_UNCHANGED), mono12)

    without = runner.invoke(app, ["detect", "--json", str(plain)])
    assert without.exit_code == 1 and json.loads(without.stdout)["error"]["code"] == "LOW_CONTRAST"
    found = runner.invoke(app, ["detect", "--json", str(marked)])
    assert found.exit_code == 0, found.output
    [hole] = json.loads(found.stdout)["holes"]
    assert np.hypot(*(np.array(hole["center"]) - view.centers_px[0])) < 0.05


def test_only_deeper_than_8_bit_mono_formats_are_marked():
    assert [_significant_bits(f) for f in ("Mono8", "Mono10", "Mono12", "Mono16", "RGB8")] == [8, 10, 12, 16, None]
