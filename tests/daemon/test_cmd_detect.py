"""`monoguide detect` on rendered images written to disk, checked against the renderer's truth."""

import json
from dataclasses import replace

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from monoguide.daemon.cli import app
from monoguide.drivers.sim.hole_renderer import HoleSpec, RenderSettings, render_view
from monoguide.solver import frames
from monoguide.solver.camera import PAPER_CAMERA

runner = CliRunner()
LOOK_DOWN = frames.make_T(np.diag([1.0, -1.0, -1.0]), np.array([0.0, 0.0, 650.0]))
# a 480 x 400 crop around the principal point of the paper's camera: the sheet seen frontally
CAMERA = replace(PAPER_CAMERA, width=480, height=400, cx=PAPER_CAMERA.cx - 1000, cy=PAPER_CAMERA.cy - 770)


@pytest.fixture(scope="module")
def example():
    """Two holes, 6 mm and 3.5 mm radius (22.4 and 13.0 px), seeded."""
    holes = [HoleSpec(np.array([1.0, 2.0, 0.0]), 6.0), HoleSpec(np.array([-25.0, 10.0, 0.0]), 3.5)]
    return render_view(CAMERA, LOOK_DOWN, holes, RenderSettings(), np.random.default_rng(0))


def _write(tmp_path, name, image):
    path = tmp_path / name
    assert cv2.imwrite(str(path), image)
    return str(path)


def test_json_gives_centres_most_plausible_first(tmp_path, example):
    path = _write(tmp_path, "roof.png", example.image)
    result = runner.invoke(app, ["detect", "--json", path])
    assert result.exit_code == 0, result.output
    record = json.loads(result.stdout.strip())
    assert record["image"] == path and record["status"] == "ok" and record["error"] is None
    assert len(record["holes"]) == 2
    for hole in record["holes"]:
        assert set(hole) == {"center", "axes", "angle_deg", "score"}
        assert 0.0 <= hole["score"] <= 1.0
    found = np.array([h["center"] for h in record["holes"]])
    for truth in example.centers_px:  # frontal view near the axis: the ellipse centre is the truth
        assert np.min(np.hypot(*(found - truth).T)) < 0.05
    radii = sorted(np.sqrt(np.prod(h["axes"])) for h in record["holes"])
    assert radii == pytest.approx([3.5 * CAMERA.fx / 650.0, 6.0 * CAMERA.fx / 650.0], rel=0.03)


def test_radius_and_roi_narrow_the_search(tmp_path, example):
    path = _write(tmp_path, "roof.png", example.image)
    big = runner.invoke(app, ["detect", "--json", "--radius-px", "22", path])
    [hole] = json.loads(big.stdout)["holes"]
    assert np.hypot(*(np.array(hole["center"]) - example.centers_px[0])) < 0.05
    u, v = example.centers_px[1]
    small = runner.invoke(app, ["detect", "--json", "--roi", f"{int(u) - 30},{int(v) - 30},60,60", path])
    [hole] = json.loads(small.stdout)["holes"]
    assert np.hypot(*(np.array(hole["center"]) - example.centers_px[1])) < 0.05


def test_table_by_default(tmp_path, example):
    path = _write(tmp_path, "roof.png", example.image)
    result = runner.invoke(app, ["detect", path])
    assert result.exit_code == 0
    assert "ok" in result.stdout
    assert f"{example.centers_px[0][0]:.1f}" in result.stdout


def test_colour_and_16_bit_files_are_read(tmp_path, example):
    colour = _write(tmp_path, "colour.png", cv2.cvtColor(example.image, cv2.COLOR_GRAY2BGR))
    deep = _write(tmp_path, "deep.png", example.image.astype(np.uint16) * 257)
    result = runner.invoke(app, ["detect", "--json", colour, deep])
    assert result.exit_code == 0
    for line in result.stdout.strip().splitlines():
        centers = np.array([h["center"] for h in json.loads(line)["holes"]])
        assert np.min(np.hypot(*(centers - example.centers_px[0]).T)) < 0.05


def test_bad_path_and_blank_image_are_error_lines_and_the_exit_status_says_so(tmp_path, example):
    good = _write(tmp_path, "roof.png", example.image)
    blank = _write(tmp_path, "blank.png", np.full((200, 200), 170, np.uint8))
    not_image = tmp_path / "notes.txt"
    not_image.write_text("not an image")
    missing = str(tmp_path / "missing.png")
    result = runner.invoke(app, ["detect", "--json", good, missing, str(not_image), blank])
    assert result.exit_code == 1
    records = [json.loads(line) for line in result.stdout.strip().splitlines()]
    assert [r["status"] for r in records] == ["ok", "error", "error", "error"]
    assert records[1]["error"]["code"] == "BAD_IMAGE" and "no such file" in records[1]["error"]["message"]
    assert records[2]["error"]["code"] == "BAD_IMAGE"
    assert records[3]["error"]["code"] == "HOLE_NOT_FOUND"
    table = runner.invoke(app, ["detect", missing])
    assert table.exit_code == 1 and "BAD_IMAGE" in table.stdout and "Traceback" not in table.stdout


def test_cut_hole_and_saturated_image_report_their_codes(tmp_path):
    cut = render_view(CAMERA, LOOK_DOWN, [HoleSpec(np.array([-63.0, 0.0, 0.0]), 6.0)], RenderSettings(),
                      np.random.default_rng(1))
    assert not cut.in_view[0]
    white = np.full((100, 100), 255, np.uint8)
    result = runner.invoke(app, ["detect", "--json", _write(tmp_path, "cut.png", cut.image),
                                 _write(tmp_path, "white.png", white)])
    codes = [json.loads(line)["error"]["code"] for line in result.stdout.strip().splitlines()]
    assert codes == ["HOLE_CUT_BY_BORDER", "IMAGE_SATURATED"]


@pytest.mark.parametrize("args", [["--roi", "1,2,3"], ["--roi", "0,0,-5,10"], ["--radius-px", "-2"]])
def test_bad_options_are_usage_errors(tmp_path, example, args):
    path = _write(tmp_path, "roof.png", example.image)
    result = runner.invoke(app, ["detect", *args, path])
    assert result.exit_code == 2
