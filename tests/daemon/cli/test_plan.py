"""`monoguide plan` through the CLI: the configured cell's layout, its bad inputs, what it writes."""

from __future__ import annotations

import itertools
import json
import re
from pathlib import Path

import cv2
import numpy as np
import pytest
from helpers.cell_configs import straight_down_cell
from helpers.figure_checks import assert_readable, describe, unit
from typer.testing import CliRunner

from monoguide.daemon.cli import app
from monoguide.daemon.cli.plan import MAP_SIZE, _render_map
from monoguide.daemon.config import load_cell_config
from monoguide.daemon.plan import LAYOUT_SIZE, cell_layout, draw_layout
from monoguide.drivers.sim.cell import part_deviation
from monoguide.solver.camera import PAPER_CAMERA
from monoguide.solver.frames import invert
from monoguide.solver.planning import assess_layout, uncertainty_map
from monoguide.solver.synthetic import PAPER_ROOF_POINTS_W

ROOT = Path(__file__).parents[3]
EXAMPLE = ROOT / "examples" / "example-record.json"
SIM_CELL = ROOT / "config" / "sim-cell.toml"


def plan(*args: str):
    return CliRunner().invoke(app, ["plan", *args])


def corner_margin(T_cf_si: np.ndarray, point: int) -> float:
    """Worst distance (px) of a hole from the image border over the 64 corners of +-50 mm / +-5 deg, by
    OpenCV's projection and the simulated cell's deviation."""
    config = load_cell_config(SIM_CELL)
    cam, points = config.camera.intrinsics, config.part.points_w
    T_si_w0 = invert(T_cf_si) @ config.reference.T_cf_w0
    worst = np.inf
    for signs in itertools.product((-1.0, 1.0), repeat=6):
        s = np.array(signs)
        T_c_w = T_si_w0 @ part_deviation(np.radians(5.0) * s[:3], 50.0 * s[3:], points.mean(axis=0))
        rvec, _ = cv2.Rodrigues(T_c_w[:3, :3])
        px, _ = cv2.projectPoints(points[point].reshape(1, 1, 3), rvec, T_c_w[:3, 3], cam.K, cam.dist_coeffs)
        u, v = px.reshape(2)
        worst = min(worst, u + 0.5, cam.width - 0.5 - u, v + 0.5, cam.height - 0.5 - v)
    return float(worst)


# --- issue 7, item 8 ------------------------------------------------------------------------------


def test_a_bad_record_fails_with_its_error_code(tmp_path: Path) -> None:
    bad = tmp_path / "bad.json"
    bad.write_text('{"format": "nope"}')
    run = plan("--steps", "3", "--record", str(bad))
    assert run.exit_code == 1
    assert "RECORD_FORMAT" in run.stderr and str(bad) in run.stderr
    assert "Fig. 5" in run.stdout  # the rest of the report is not lost
    broken = tmp_path / "broken.json"
    broken.write_bytes(b"\xff\xfe{")
    run = plan("--steps", "3", "--json", "--record", str(broken))
    assert run.exit_code == 1 and "RECORD_INVALID" in run.stderr
    assert json.loads(run.stdout)["record"]["error"]["code"] == "RECORD_INVALID"


@pytest.mark.parametrize("value", ["nan", "inf", "-0.1", "0"])
def test_a_bad_sigma_is_a_bad_option(value: str) -> None:
    run = plan("--sigma-px", value)
    assert run.exit_code == 2 and "--sigma-px" in run.stderr and "Traceback" not in run.output


def test_the_map_is_said_to_be_written_only_when_it_was(tmp_path: Path) -> None:
    missing = tmp_path / "no" / "such" / "dir" / "fig5.png"
    run = plan("--steps", "3", "--out", str(missing))
    assert run.exit_code == 1 and "--out" in run.stderr and "not written" in run.stderr
    assert "written" not in run.stdout and not missing.exists()
    run = plan("--steps", "3", "--out", str(tmp_path / "fig5.txt"))
    assert run.exit_code == 2 and "--out" in run.stderr
    out = tmp_path / "fig5.png"
    run = plan("--steps", "4", "--out", str(out))
    assert run.exit_code == 0 and f"Map written to {out}" in run.stdout
    image = cv2.imread(str(out))
    assert image is not None and image.shape == (MAP_SIZE[1], MAP_SIZE[0], 3)
    assert (cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) < 128).mean() > 0.2  # the map is drawn, not a blank page


def test_the_fig5_map_has_pixel_axes_and_a_colour_bar_spanning_the_map() -> None:
    """The paper's camera (2456 x 2058 px): the axes cover the image quadrant, 0..1228 px along u and
    1029..0 px along v (downwards, as in the image); the log colour scale runs from the map's smallest sigma
    to its largest, in mm; the quarter-from-the-edge position is marked at (614, 514.5) px and named."""
    fig5 = uncertainty_map(PAPER_CAMERA, PAPER_ROOF_POINTS_W, 650.0, steps=4)
    seen = describe(_render_map(fig5, PAPER_CAMERA.width, PAPER_CAMERA.height))
    assert_readable(seen)
    (ax,) = seen["axes"]
    assert unit(ax["x"]) == "px" and unit(ax["y"]) == "px" and ax["equal"]
    assert ax["xlim"] == (0.0, 1228.0) and ax["ylim"] == (1029.0, 0.0)
    ((label, low, high, values),) = seen["colorbars"]
    assert unit(label) == "mm" and "log" in label
    assert (low, high) == (fig5.sigma_trans_mm.min(), fig5.sigma_trans_mm.max()) and low < high
    np.testing.assert_array_equal(np.sort(values.ravel()), np.sort(fig5.sigma_trans_mm.ravel()))
    ((marker, (u, v)),) = [(k, p) for k, p in ax["points"].items() if "quarter" in k]
    assert (u.tolist(), v.tolist()) == ([614.0], [514.5]) and marker in seen["legend"]
    assert seen["size"] == MAP_SIZE and any("Fig. 5" in t for t in seen["titles"])


def test_the_fig5_study_is_made_for_the_configured_camera(tmp_path: Path) -> None:
    """A cell with another camera (1600 x 1200 px): the quarter positions are that camera's, by hand
    (u = 799.5 -+ 400, v = 599.5 -+ 300), not the paper's."""
    text = SIM_CELL.read_text()
    for key, value in (("width", "1600"), ("height", "1200"), ("cx", "801.0"), ("cy", "598.0")):
        text = re.sub(rf"^{key} = .*$", f"{key} = {value}", text, flags=re.MULTILINE)
    config = tmp_path / "other-camera.toml"
    config.write_text(text)
    run = plan("--config", str(config), "--steps", "3", "--json")
    assert run.exit_code == 0, run.output
    report = json.loads(run.stdout)
    assert report["camera"].startswith("1600 x 1200 px")
    np.testing.assert_allclose(report["recommended_pixels"],
                               [[1199.5, 299.5], [399.5, 299.5], [399.5, 899.5], [1199.5, 899.5]])
    paper = json.loads(plan("--steps", "3", "--json").stdout)
    assert paper["camera"].startswith("2456 x 2058 px")


def test_example_record_layout_is_reported() -> None:
    run = plan("--json", "--steps", "3", "--record", str(EXAMPLE))
    assert run.exit_code == 0, run.output
    record = json.loads(run.stdout)["record"]
    assert 0.0 < record["sigma_trans_mm"] < record["sigma_origin_mm"]


# --- issue 8: --layout ------------------------------------------------------------------------------


def test_layout_plans_the_configured_cell_and_holds_the_envelope(tmp_path: Path) -> None:
    cell = straight_down_cell(tmp_path)
    picture = tmp_path / "layout.png"
    run = plan("--layout", "--config", str(cell), "--json", "--out", str(picture))
    assert run.exit_code == 0, run.output
    report = json.loads(run.stdout)
    for key in ("sigma_rot_deg", "sigma_trans_mm", "margin_px_min", "depth_mm_min", "depth_mm_max"):
        assert isinstance(report[key], float)
    assert report["sigma_rot_deg"] <= 0.0045 and report["sigma_origin_mm"] <= 0.075
    assert report["sigma_trans_mm_with_repeatability"] < report["current"]["sigma_trans_mm_with_repeatability"]
    assert report["sigma_rot_deg_with_repeatability"] < report["current"]["sigma_rot_deg_with_repeatability"]
    assert 450.0 <= report["depth_mm_min"] <= report["depth_mm_max"] <= 900.0
    margins = [corner_margin(np.array(p["T_cf_si"]), i) for i, p in enumerate(report["poses"])]
    assert min(margins) >= 100.0 and report["margin_px_min"] == pytest.approx(min(margins), abs=0.05)
    current = [corner_margin(np.array(p["T_cf_si"]), i) for i, p in enumerate(report["current"]["poses"])]
    assert report["current"]["margin_px_min"] == pytest.approx(min(current), abs=0.05) and min(current) < -300
    image = cv2.imread(str(picture))
    assert image is not None and image.shape == (LAYOUT_SIZE[1], LAYOUT_SIZE[0], 3)
    assert report["layout_png"] == str(picture)


def test_the_layout_drawing_is_to_scale_in_mm_and_shows_every_camera_and_hole(tmp_path: Path) -> None:
    """The simulated cell's poses (its plan) drawn beside the hand-written straight-down ones: both views in mm
    at equal scale, every hole where the config puts it, the four planned cameras where the config's
    ``T_cf_si`` put them, the current cameras 650 mm above their holes (as written above), a legend naming
    all of it."""
    config, straight = load_cell_config(SIM_CELL), load_cell_config(straight_down_cell(tmp_path))
    cell = cell_layout(config, None)
    planned = assess_layout(cell.request, cell.T_w0_si, cell.observed)
    current = [invert(straight.reference.T_cf_w0) @ p.T_cf_si for p in straight.measuring_poses]
    seen = describe(draw_layout(cell.request, planned, current, title="the cell"))
    assert_readable(seen)
    above, side = seen["axes"]
    assert [unit(ax["x"]) for ax in (above, side)] == ["mm", "mm"] and above["equal"] and side["equal"]
    assert [unit(ax["y"]) for ax in (above, side)] == ["mm", "mm"] and "z" in side["y"] and "y" in above["y"]
    points = config.part.points_w
    np.testing.assert_allclose(np.column_stack(above["points"]["featured hole"]), points[:, :2])
    np.testing.assert_allclose(side["points"]["featured hole"][1], points[:, 2])
    current = np.column_stack(side["points"]["the cell's current cameras"])
    np.testing.assert_allclose(current[:, 1], points[:, 2] + 650.0, atol=1e-6)  # straight down from 650 mm
    for i, pose in enumerate(config.measuring_poses):
        apex = next(p for k, p in above["points"].items() if k.startswith(f"S{i + 1}:"))
        T_w0_si = invert(config.reference.T_cf_w0) @ pose.T_cf_si
        np.testing.assert_allclose([apex[0][0], apex[1][0]], T_w0_si[:2, 3])
    legend = seen["legend"]
    assert sum(e.startswith("S") for e in legend) == 4 and "featured hole" in legend
    assert any("64 corners" in e for e in legend) and seen["size"] == LAYOUT_SIZE


def test_layout_human_output_puts_the_plan_beside_the_cell(tmp_path: Path) -> None:
    run = plan("--layout", "--config", str(straight_down_cell(tmp_path)))
    assert run.exit_code == 0, run.output
    lines = run.stdout.splitlines()
    assert any(line.startswith("│ current") for line in lines) and any(line.startswith("│ planned") for line in lines)
    assert sum("│ S" in line for line in lines) == 8  # four poses, current and planned


def test_write_gives_a_copy_with_the_planned_poses_and_nothing_else_changed(tmp_path: Path) -> None:
    cell = straight_down_cell(tmp_path)
    new = tmp_path / "planned.toml"
    run = plan("--layout", "--config", str(cell), "--write", str(new), "--json")
    assert run.exit_code == 0, run.output
    report = json.loads(run.stdout)
    assert report["written"] == str(new)
    after = load_cell_config(new)
    for pose, planned in zip(after.measuring_poses, report["poses"], strict=True):
        np.testing.assert_allclose(pose.T_cf_si, planned["T_cf_si"], atol=1e-9)
        assert pose.name == planned["name"]
    assert [p.points for p in after.measuring_poses] == [(0,), (1,), (2,), (3,)]
    old_text, new_text = cell.read_text(), new.read_text()
    assert old_text[: old_text.index("[[measuring_poses]]")] == new_text[: new_text.index("[[measuring_poses]]")]
    assert old_text[old_text.index("[tracker]") :] == new_text[new_text.index("[tracker]") :]
    again = plan("--layout", "--config", str(new), "--json")  # the copy is planned again to the same poses
    for pose, planned in zip(json.loads(again.stdout)["current"]["poses"], report["poses"], strict=True):
        np.testing.assert_allclose(pose["T_cf_si"], planned["T_cf_si"], atol=1e-6)


def test_write_on_a_cell_of_part_types_replaces_the_planned_parts_poses_and_keeps_the_others(tmp_path: Path) -> None:
    """config/sim-cell.toml ([[parts]]: the roof planned, job 1) with the roof's poses moved away from the plan:
    the written copy has the planned roof poses under their names, the roof's views one pose per hole, and the
    hood's poses (S5-S7) and everything of job 2 exactly as they were."""
    text = SIM_CELL.read_text()
    moved = re.sub(r"(name = \"S1\".*?T_cf_si = \[\n    \[[^\]]*?, )(-?\d+\.\d+)\]",
                   lambda m: m.group(1) + f"{float(m.group(2)) + 40.0:.12f}]", text, count=1, flags=re.S)
    assert moved != text
    cell, new = tmp_path / "cell.toml", tmp_path / "planned.toml"
    cell.write_text(moved)
    run = plan("--layout", "--config", str(cell), "--write", str(new), "--json")
    assert run.exit_code == 0, run.output
    report = json.loads(run.stdout)
    before, after = load_cell_config(SIM_CELL), load_cell_config(new)
    assert [p.name for p in after.cell_poses] == [p.name for p in before.cell_poses]
    for pose, planned in zip(after.for_job(1).measuring_poses, report["poses"], strict=True):
        assert pose.name == planned["name"]
        np.testing.assert_allclose(pose.T_cf_si, planned["T_cf_si"], atol=1e-9)
    for old, kept in zip(before.for_job(2).measuring_poses, after.for_job(2).measuring_poses, strict=True):
        assert (old.name, old.points, old.number) == (kept.name, kept.points, kept.number)
        np.testing.assert_allclose(kept.T_cf_si, old.T_cf_si, atol=1e-12)
    np.testing.assert_allclose(after.for_job(2).reference.T_cf_w0, before.for_job(2).reference.T_cf_w0, atol=1e-12)


def test_the_generated_sim_cell_is_already_on_its_plan() -> None:
    run = plan("--layout", "--config", str(SIM_CELL), "--json")
    assert run.exit_code == 0, run.output
    report = json.loads(run.stdout)
    for current, planned in zip(report["current"]["poses"], report["poses"], strict=True):
        np.testing.assert_allclose(current["T_cf_si"], planned["T_cf_si"], atol=1e-6)


def test_an_infeasible_layout_is_refused_naming_the_constraint(tmp_path: Path) -> None:
    cell = straight_down_cell(tmp_path, extra="depth_of_field_mm = [640.0, 660.0]")
    new = tmp_path / "never.toml"
    run = plan("--layout", "--config", str(cell), "--write", str(new))
    assert run.exit_code == 1 and not new.exists()
    assert "LAYOUT_DEPTH_OF_FIELD " in run.stderr and "depth_of_field_mm" in run.stderr
    run = plan("--layout", "--config", str(cell), "--json")
    assert run.exit_code == 1
    assert json.loads(run.stdout) == {"status": "error", "error": {
        "code": "LAYOUT_DEPTH_OF_FIELD", "plc_code": 514, "message": json.loads(run.stdout)["error"]["message"]}}


@pytest.mark.parametrize(
    ("args", "option"),
    [
        (["--layout"], "--config"),
        (["--write", "x.toml"], "--write"),
        (["--layout", "--config", str(SIM_CELL), "--write", str(SIM_CELL)], "--write"),
        (["--steps", "1"], "--steps"),
        (["--standoff-mm", "nan"], "--standoff-mm"),
    ],
)
def test_bad_option_combinations_exit_2_naming_the_option(args: list[str], option: str) -> None:
    run = plan(*args)
    assert run.exit_code == 2 and option in run.stderr


def test_a_bad_config_fails_with_its_code(tmp_path: Path) -> None:
    run = plan("--layout", "--config", str(tmp_path / "none.toml"))
    assert run.exit_code == 2 and "CONFIG" in run.stderr and "none.toml" in run.stderr  # a bad config: 2


@pytest.mark.parametrize(
    ("old", "new", "says"),
    [
        (r"^standoff_mm = .*$", "standoff_mm = [900.0, 400.0]", "standoff_mm = [900.0, 400.0]"),
        (r"^max_view_angle_deg = .*$", "max_view_angle_deg = 95.0", "max_view_angle_deg = 95.0"),
        (r"^margin_px = .*$", "margin_pixels = 50.0", "margin_px"),  # unknown: the closest known key is suggested
    ],
)
def test_a_bad_layout_section_is_refused_naming_the_key(tmp_path: Path, old: str, new: str, says: str) -> None:
    config = tmp_path / "cell.toml"
    config.write_text(re.sub(old, new, SIM_CELL.read_text(), count=1, flags=re.MULTILINE))
    run = plan("--layout", "--config", str(config))
    assert run.exit_code == 2 and says in run.stderr and "CONFIG" in run.stderr and "[layout]" in run.stderr


def test_the_grasp_point_of_the_config_is_where_sigma_is_predicted(tmp_path: Path) -> None:
    """[part] grasp_point_w moved to hole P1 (the part origin): the grasp-point sigma becomes the origin's."""
    text = SIM_CELL.read_text().replace("hole_radius_mm = 5.0", "hole_radius_mm = 5.0\ngrasp_point_w = [0.0, 0.0, 0.0]")
    config = tmp_path / "cell.toml"
    config.write_text(text)
    report = json.loads(plan("--layout", "--config", str(config), "--json").stdout)
    assert report["grasp_point_w"] == [0.0, 0.0, 0.0]
    assert report["current"]["sigma_trans_mm"] == pytest.approx(report["current"]["sigma_origin_mm"], abs=2e-6)


def test_write_edits_the_file_as_toml_keeping_the_comments_that_introduce_the_next_table(tmp_path: Path) -> None:
    """The copy is the source edited as a TOML document: the old poses go with their own comments, the comment
    lines directly above the table after them stay there, a multi-line string (which a line-by-line editor
    could not see through) is kept."""
    cell = straight_down_cell(tmp_path)
    text = cell.read_text().replace('\nname = "S2"', '\n# S2 by hand\nname = "S2"', 1)
    text = text.replace("\n[tracker]", "\n# the devices\n[tracker]", 1)
    text = text.replace('name = "paper roof cell (simulated)"', 'name = """paper roof cell\n[simulated]"""', 1)
    cell.write_text(text)
    new = tmp_path / "planned.toml"
    run = plan("--layout", "--config", str(cell), "--write", str(new), "--json")
    assert run.exit_code == 0, run.output
    written = new.read_text()
    assert "# S2 by hand" not in written and written.count("  # planned by `monoguide plan --layout`") == 4
    assert re.search(r"\n\]\n\n# the devices\n\[tracker\]", written)
    assert load_cell_config(new).name == "paper roof cell\n[simulated]"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cell.toml", "planned.toml"]  # no temporary file left
