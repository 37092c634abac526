"""[[parts]]: part types selected by the PLC's job number. Both forms load; the single-part form of
config/sim-cell.toml (as shipped before part types) and the template read as job 1, unchanged in meaning; every
error names the part and the key."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

import numpy as np
import pytest
from helpers.repository import CONFIG_DIR, SIM_CELL, SINGLE_PART_SIM_CELL

from monoguide.daemon.config import load_cell_config
from monoguide.drivers.errors import ConfigError

TEMPLATE = CONFIG_DIR / "cell-template.toml"


def _load(tmp_path: Path, text: str) -> object:
    path = tmp_path / "cell.toml"
    path.write_text(text)
    return load_cell_config(path)


def _hood_views(text: str, views: str) -> str:
    """The shipped cell with the hood's `measuring_poses = {...}` replaced."""
    out, n = re.subn(r'measuring_poses = \{ S5 = \[[^}]*\}', f"measuring_poses = {views}", text)
    assert n == 1
    return out


def test_the_single_part_form_reads_as_job_1_as_it_did() -> None:
    """The file as shipped before part types, read now: one part, job 1, its poses numbered 1..4 and seeing the
    holes its `points` said; the same values as job 1 of today's two-part file (generated from the same plan)."""
    raw = tomllib.loads(SINGLE_PART_SIM_CELL.read_text())
    old, new = load_cell_config(SINGLE_PART_SIM_CELL), load_cell_config(SIM_CELL)
    assert old.jobs == (1,) and old.part_name == "part" and old.for_job(1) is old
    assert [p.points for p in old.measuring_poses] == [tuple(p["points"]) for p in raw["measuring_poses"]]
    assert [p.number for p in old.measuring_poses] == [1, 2, 3, 4] and old.cell_poses == old.measuring_poses
    np.testing.assert_allclose(old.reference.T_cf_w0, np.array(raw["reference"]["T_cf_w0"]), atol=1e-9)
    np.testing.assert_array_equal(old.part.points_w, np.array(raw["part"]["points_w"]))
    roof = new.for_job(1)
    assert roof.part_name == "roof" and [p.name for p in roof.measuring_poses] == [p.name for p in old.measuring_poses]
    np.testing.assert_allclose(roof.reference.T_cf_w0, old.reference.T_cf_w0, atol=1e-9)
    for a, b in zip(roof.measuring_poses, old.measuring_poses, strict=True):
        assert (a.points, a.number) == (b.points, b.number)
        np.testing.assert_allclose(a.T_cf_si, b.T_cf_si, atol=1e-9)


def test_the_template_reads_as_job_1() -> None:
    config = load_cell_config(TEMPLATE)
    assert config.jobs == (1,) and config.part_name == "part" and len(config.parts) == 1


def test_two_part_types_with_their_own_holes_poses_and_references() -> None:
    raw = tomllib.loads(SIM_CELL.read_text())
    config = load_cell_config(SIM_CELL)
    assert config.jobs == (1, 2) and [p.name for p in config.parts] == ["roof", "hood"]
    assert [p.name for p in config.cell_poses] == [f"S{k}" for k in range(1, 8)]
    hood = config.for_job(2)
    assert (hood.job, hood.part_name, len(hood.part.points_w)) == (2, "hood", 6)
    assert [(p.name, p.number, p.points) for p in hood.measuring_poses] == [
        ("S5", 5, (0, 1)), ("S6", 6, (2, 3)), ("S7", 7, (4, 5))]
    np.testing.assert_allclose(hood.reference.T_cf_w0, np.array(raw["parts"][1]["T_cf_w0"]), atol=1e-9)
    np.testing.assert_array_equal(hood.reference.T_cf_b, config.reference.T_cf_b)  # the robot base is the cell's
    assert config.for_job(2) is hood  # built once: a job switch is a lookup
    assert len(config.cell_taught_flange_poses()) == 7 and len(hood.taught_flange_poses()) == 3
    with pytest.raises(ConfigError, match=r"no part of job 3; the cell's jobs are job 1 \('roof'\), job 2 \('hood'\)"):
        config.for_job(3)


def test_two_parts_may_share_a_measuring_pose_each_seeing_its_own_holes(tmp_path: Path) -> None:
    text = _hood_views(SIM_CELL.read_text(), '{ S1 = ["H1"], S5 = ["H1", "H2"], S6 = ["H3", "H4"], S7 = ["H5", "H6"] }')
    config = _load(tmp_path, text)
    roof, hood = config.for_job(1), config.for_job(2)
    assert roof.measuring_poses[0].name == hood.measuring_poses[0].name == "S1"
    assert (roof.measuring_poses[0].points, hood.measuring_poses[0].points) == ((0,), (0,))
    np.testing.assert_array_equal(roof.measuring_poses[0].T_cf_si, hood.measuring_poses[0].T_cf_si)
    assert [p.name for p in hood.measuring_poses] == ["S1", "S5", "S6", "S7"]  # in the cell's pose order


@pytest.mark.parametrize(("change", "message"), [
    (lambda t: t.replace("job = 2", "job = 1", 1),
     r"\[\[parts\]\] #2 \(job 1, 'hood'\)\.job = 1: already the job of \[\[parts\]\] 'roof'"),
    (lambda t: t.replace('name = "hood"', 'name = "roof"', 1),
     r"\[\[parts\]\] #2 \(job 2, 'roof'\)\.name = 'roof': already the name of \[\[parts\]\] job 1"),
    (lambda t: t.replace("job = 2", "job = 0", 1), r"\[\[parts\]\] #2\.job = 0: must be 1 to 65534"),
    (lambda t: t.replace("job = 2", "job = 65535", 1), r"\[\[parts\]\] #2\.job = 65535: must be 1 to 65534"),
    (lambda t: _hood_views(t, '{ S55 = ["H1", "H2"], S6 = ["H3", "H4"] }'),
     r"\(job 2, 'hood'\)\.measuring_poses\.S55: no such \[\[measuring_poses\]\] in the cell; did you mean 'S5'\?"),
    (lambda t: _hood_views(t, '{ S8 = ["H1", "H2"], S6 = ["H3", "H4"] }'),
     r"\.measuring_poses\.S8: no such \[\[measuring_poses\]\] in the cell; the cell's poses are S1, S2, .*, S7"),
    (lambda t: _hood_views(t, '{ S5 = ["H1", "H1"], S6 = ["H3", "H4"], S7 = ["H5", "H6"] }'),
     r"\(job 2, 'hood'\)\.measuring_poses\.S5 = \['H1', 'H1'\]: \['H1'\] listed twice"),
    (lambda t: _hood_views(t, '{ S5 = ["H1", "HX"], S6 = ["H3", "H4"] }'),
     r"\(job 2, 'hood'\)\.measuring_poses\.S5 = \['H1', 'HX'\]: 'HX' is not a hole of this part"),
    (lambda t: _hood_views(t, '{ S5 = [], S6 = ["H3", "H4"] }'),
     r"\(job 2, 'hood'\)\.measuring_poses\.S5 = \[\]: a view sees at least one featured hole"),
    (lambda t: t.replace('name = "hood"', 'name = "hood"\nhole_radius = 4.0', 1),
     r"\[\[parts\]\] #2\.hole_radius: unknown key; did you mean 'hole_radius_mm'\?"),
    (lambda t: t.replace('name = "S5"', 'name = "S5"\npoints = [0]', 1),
     r"\[\[measuring_poses\]\] #5\.points: in a cell of \[\[parts\]\] each part says which of its holes"),
    (lambda t: t.replace('name = "S6"', 'name = "S5"', 1),
     r"\[\[measuring_poses\]\] #6\.name = 'S5': already the name of \[\[measuring_poses\]\] #5"),
    (lambda t: t.replace("[reference]", "[reference]\nT_cf_w0 = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], "
                         "[0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]", 1),
     r"\[reference\]\.T_cf_w0: in a cell of \[\[parts\]\] each part has its own reference"),
    (lambda t: t.replace("[reference]", "[part]\nhole_radius_mm = 5.0\npoints_w = [[0.0, 0.0, 0.0]]\n\n[reference]",
                         1), r"\[part\] and \[\[parts\]\]: give one"),
], ids=["job twice", "name twice", "job 0", "job 65536", "misspelt pose", "unknown pose", "a hole twice in a view",
        "unknown hole", "empty view", "unknown key", "points in a shared pose", "a pose name (and number) twice",
        "T_cf_w0 in [reference]", "[part] beside [[parts]]"])
def test_every_error_names_the_part_and_the_key(tmp_path: Path, change, message: str) -> None:
    text = change(SIM_CELL.read_text())
    assert text != SIM_CELL.read_text()
    with pytest.raises(ConfigError, match=message):
        _load(tmp_path, text)


def test_a_part_whose_views_see_three_holes_once_each_lacks_the_redundancy_and_is_named(tmp_path: Path) -> None:
    """Three hole images: 2 x 3 - 6 = 0 degrees of freedom, no consistency check: refused for a cell that runs
    cycles, naming the part type; the roof (four images) is fine."""
    text = _hood_views(SIM_CELL.read_text(), '{ S5 = ["H1"], S6 = ["H3"], S7 = ["H5"] }')
    with pytest.raises(ConfigError, match=r"\[\[parts\]\] job 2 \('hood'\): measuring_poses S5, S6, S7: see 3 hole "
                                          r"image\(s\)"):
        _load(tmp_path, text)


def test_a_part_with_three_holes_seen_twice_each_is_enough(tmp_path: Path) -> None:
    """A part of three holes: two views that see all three (6 images, 6 degrees of freedom) load."""
    text = SIM_CELL.read_text()
    text = text.replace('point_names = ["H1", "H2", "H3", "H4", "H5", "H6"]', 'point_names = ["H1", "H2", "H3"]')
    text = re.sub(r"(points_w = \[\[150\.0, 120\.0, 0\.0\], \[400\.0, 120\.0, 0\.0\], \[1380\.0, 180\.0, 0\.0\])"
                  r"[^\n]*\]", r"\1]", text)
    text = _hood_views(text, '{ S5 = ["H1", "H2", "H3"], S6 = ["H1", "H2", "H3"] }')
    hood = _load(tmp_path, text).for_job(2)
    assert len(hood.part.points_w) == 3 and [p.points for p in hood.measuring_poses] == [(0, 1, 2), (0, 1, 2)]
