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


def _twelve_bit(example_image: np.ndarray) -> np.ndarray:
    """The rendered image as a Mono12 camera delivers it: 0..4095 in a uint16 array (noise kept)."""
    return np.round(example_image.astype(float) * (4095.0 / 255.0)).astype(np.uint16)


def _with_sbit(png: bytes, bits: int) -> bytes:
    """``png`` with an sBIT chunk (significant bits of the grey samples) after its IHDR chunk."""
    import struct
    import zlib

    ihdr_end = 8 + 8 + 13 + 4
    chunk = struct.pack(">I4sB", 1, b"sBIT", bits) + struct.pack(">I", zlib.crc32(b"sBIT" + bytes([bits])))
    return png[:ihdr_end] + chunk + png[ihdr_end:]


def test_12_bit_data_in_a_16_bit_png_is_scaled_by_its_bit_depth(tmp_path, example):
    path = _write(tmp_path, "mono12.png", _twelve_bit(example.image))
    result = runner.invoke(app, ["detect", "--json", "--bit-depth", "12", path])
    assert result.exit_code == 0, result.output
    found = np.array([h["center"] for h in json.loads(result.stdout)["holes"]])
    assert len(found) == 2
    for truth in example.centers_px:
        assert np.min(np.hypot(*(found - truth).T)) < 0.05
    # read as 16-bit data the rim has a sixteenth of its contrast: refused, with a hint at the bit depth
    plain = runner.invoke(app, ["detect", "--json", path])
    assert plain.exit_code == 1
    error = json.loads(plain.stdout)["error"]
    assert error["code"] in ("LOW_CONTRAST", "HOLE_NOT_FOUND") and "--bit-depth 12" in error["message"]


def test_the_png_sbit_chunk_gives_the_bit_depth(tmp_path, example):
    ok, png = cv2.imencode(".png", _twelve_bit(example.image))
    assert ok
    path = tmp_path / "mono12-sbit.png"
    path.write_bytes(_with_sbit(png.tobytes(), 12))
    result = runner.invoke(app, ["detect", "--json", str(path)])
    assert result.exit_code == 0, result.output
    found = np.array([h["center"] for h in json.loads(result.stdout)["holes"]])
    assert np.min(np.hypot(*(found - example.centers_px[0]).T)) < 0.05


def test_data_above_the_bit_depth_is_refused(tmp_path, example):
    path = _write(tmp_path, "deep.png", example.image.astype(np.uint16) * 257)  # 16-bit data
    result = runner.invoke(app, ["detect", "--json", "--bit-depth", "12", path])
    assert result.exit_code == 1
    error = json.loads(result.stdout)["error"]
    assert error["code"] == "BAD_IMAGE" and "12-bit" in error["message"]


@pytest.mark.parametrize("kind", ["uniform", "gaussian"])
def test_pure_noise_has_no_holes(tmp_path, kind):
    rng = np.random.default_rng(0)
    shape = (2058, 2456)
    noise = (rng.integers(0, 256, shape) if kind == "uniform" else np.clip(rng.normal(128.0, 40.0, shape), 0, 255))
    path = _write(tmp_path, "noise.png", noise.astype(np.uint8))
    result = runner.invoke(app, ["detect", "--json", path])
    assert result.exit_code == 1
    record = json.loads(result.stdout)
    assert record["holes"] == [] and record["error"]["code"] == "HOLE_NOT_FOUND"


def test_a_roi_smaller_than_the_hole_selects_it_by_its_centre(tmp_path, example):
    path = _write(tmp_path, "roof.png", example.image)
    u, v = example.centers_px[0]  # the 22 px hole: a 20 x 20 ROI lies inside it
    result = runner.invoke(app, ["detect", "--json", "--roi", f"{round(u) - 10},{round(v) - 10},20,20", path])
    assert result.exit_code == 0, result.output
    [hole] = json.loads(result.stdout)["holes"]
    assert np.hypot(*(np.array(hole["center"]) - example.centers_px[0])) < 0.05
    # a ROI that holds part of the hole but not its centre lists nothing
    beside = runner.invoke(app, ["detect", "--json", "--roi", f"{round(u) + 8},{round(v) - 10},20,20", path])
    assert beside.exit_code == 1 and json.loads(beside.stdout)["holes"] == []


@pytest.mark.parametrize(("args", "option"), [
    (["--roi", "1,2,3"], "--roi"), (["--roi", "0,0,-5,10"], "--roi"), (["--roi", "-1,0,5,10"], "--roi"),
    (["--radius-px", "-1"], "--radius-px"), (["--radius-px", "nan"], "--radius-px"),
    (["--radius-px", "inf"], "--radius-px"), (["--bit-depth", "7"], "--bit-depth"),
    (["--bit-depth", "17"], "--bit-depth"), (["--bit-depth", "twelve"], "--bit-depth"),
])
def test_bad_options_exit_2_naming_the_option(tmp_path, example, args, option):
    path = _write(tmp_path, "roof.png", example.image)
    result = runner.invoke(app, ["detect", *args, path])
    assert result.exit_code == 2
    assert option in result.stderr and result.stdout == ""


def test_human_output_puts_error_lines_on_standard_error(tmp_path, example):
    good = _write(tmp_path, "roof.png", example.image)
    missing = str(tmp_path / "missing.png")
    result = runner.invoke(app, ["detect", good, missing])
    assert result.exit_code == 1
    assert f"{example.centers_px[0][0]:.1f}" in result.stdout
    assert "no such file" not in result.stdout
    [line] = [line for line in result.stderr.splitlines() if "BAD_IMAGE" in line]  # piped: one unwrapped line
    assert line.endswith("missing.png: no such file")
