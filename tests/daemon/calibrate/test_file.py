"""``daemon/calibrate/_file.py``: the wizard's values written into a copy of a cell config, in place.

Seeded perturbations of the committed configs' values are the ground truth: the rewritten file must load them
back (to 1e-9), keep every other line, comment and the simulated truth, keep the previous file and name it, and
refuse (changing nothing) what would not load.
"""

from __future__ import annotations

import errno
import re
import shutil
import stat
import tomllib
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import tomlkit
from helpers.calibration_text_editor import edit_calibration_text

from monoguide.daemon.calibrate import open_session, read_calibration_provenance, write_calibration
from monoguide.daemon.calibrate._file import _calibrated_values, _provenance
from monoguide.daemon.cli.calibrate import write_results
from monoguide.daemon.config import load_cell_config
from monoguide.daemon.errors import (
    CalibrationFileError,
    CalibrationFileRefused,
    CalibrationFileUneditable,
    CalibrationValueInvalid,
)
from monoguide.drivers import atomic_file
from monoguide.solver.frames import make_T, rotvec_to_matrix

CONFIG_DIR = Path(__file__).parents[3] / "config"
INTRINSICS = ("width", "height", "fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2")
PROVENANCE = {"session": "/var/lib/monoguide/calibration-session.json", "sim": True,
              "devices": {"camera": "sim camera SIM-1", "tracker": "sim tracker LT-1", "robot": "sim-ur UR-1"}}


def _perturbed(T: np.ndarray, rng: np.random.Generator, mm: float = 3.0, deg: float = 0.3) -> np.ndarray:
    """T moved by a seeded rigid perturbation (exactly orthonormal, as a calibration step returns it)."""
    return T @ make_T(rotvec_to_matrix(np.radians(rng.normal(0.0, deg, 3))), rng.normal(0.0, mm, 3))


def _steps(path: Path, seed: int) -> dict[str, dict[str, Any]]:
    """Results of intrinsics, base, part and sfi (docs/calibration.md), seeded, for the config at ``path``."""
    config, rng = load_cell_config(path), np.random.default_rng(seed)
    camera = config.camera.intrinsics.as_dict() | {"fx": 2400.0 + rng.uniform(0, 50), "fy": 2400.0 + rng.uniform(0, 50),
                                                  "cx": 1228.0 + rng.normal(0, 9), "k1": float(rng.normal(0, 0.02))}
    T_f_c = config.camera.T_f_c if config.camera.T_f_c is not None else np.eye(4)
    return {
        "intrinsics": {"camera": camera, "rms_px": 0.14, "per_image_rms_px": [0.1, 0.2], "rejected": {"3": "blurred"},
                       "images": 12, "done": "2025-06-01T10:00:00+00:00"},
        "cell": {"method": "best-fit", "T_cf_tracker": np.eye(4).tolist(), "residuals_mm": {"B1": 0.01, "B2": 0.03},
                 "rms_mm": 0.02, "truth_error": {"cell_mm": 0.011, "cell_deg": 0.001}},
        "base": {"T_cf_b": _perturbed(config.reference.T_cf_b, rng).tolist(), "smr_f": [0, 0, 250],
                 "residuals_mm": [0.01, 0.05, 0.02], "rms_mm": 0.03, "sigma_mm": 0.01, "sigma_deg": 0.0004,
                 "flange_poses": []},
        "part": {"T_cf_w0": _perturbed(config.reference.T_cf_w0, rng).tolist(), "residuals_mm": {"P1": 0.02},
                 "rms_mm": 0.02},
        "sfi": {"poses": [{"name": p.name, "T_cf_si": _perturbed(p.T_cf_si, rng).tolist(), "spread_mm": 0.1 + i,
                           "spread_deg": 0.01, "sem_mm": 0.02, "sem_deg": 0.002, "visits": 4,
                           "deviations_mm": [0.1] * 4} for i, p in enumerate(config.measuring_poses)],
                "T_f_c": _perturbed(T_f_c, rng, 2.0, 0.2).tolist(), "T_f_c_spread_mm": 0.1, "T_f_c_spread_deg": 0.01},
    }


def _copy(tmp_path: Path, name: str) -> Path:
    target = tmp_path / "cell.toml"
    shutil.copyfile(CONFIG_DIR / name, target)
    return target


def _assert_loads(path: Path, steps: dict[str, dict[str, Any]]) -> None:
    config = load_cell_config(path)
    for key in INTRINSICS:
        assert getattr(config.camera.intrinsics, key) == steps["intrinsics"]["camera"][key], key
    np.testing.assert_allclose(config.camera.T_f_c, steps["sfi"]["T_f_c"], rtol=0, atol=1e-9)
    np.testing.assert_allclose(config.reference.T_cf_b, steps["base"]["T_cf_b"], rtol=0, atol=1e-9)
    np.testing.assert_allclose(config.reference.T_cf_w0, steps["part"]["T_cf_w0"], rtol=0, atol=1e-9)
    for pose, expected in zip(config.measuring_poses, steps["sfi"]["poses"], strict=True):
        np.testing.assert_allclose(pose.T_cf_si, expected["T_cf_si"], rtol=0, atol=1e-9)


def _without_calibrated_values(text: str) -> str:
    """The text with the calibrated keys' values blanked (matrices of 4 rows, intrinsics) and [calibration] cut."""
    text = text.split("\n[calibration]")[0]
    text = re.sub(r"^(T_f_c|T_cf_b|T_cf_w0|T_cf_si) = \[([^\n]*)\n(    \[[^\n]*\],\n){4}\]", r"\1 = [\2 ...]", text,
                  flags=re.M)
    return re.sub(rf"^({'|'.join(INTRINSICS)}) = [^\n#]*", r"\1 = ...", text, flags=re.M)


def test_a_round_trip_loads_what_was_written_and_keeps_every_other_line(tmp_path: Path) -> None:
    path = _copy(tmp_path, "sim-cell.toml")
    before = path.read_text()
    truth = load_cell_config(path).sim
    steps = _steps(path, seed=12)
    assert write_calibration(path, steps, PROVENANCE) == path
    _assert_loads(path, steps)
    after = path.read_text()
    assert _without_calibrated_values(after) == _without_calibrated_values(before)
    assert after.count("\n") - before.count("\n") == len(after.split("\n[calibration]")[1].splitlines()) + 1
    sim = load_cell_config(path).sim  # the simulated truth is not a calibrated value
    np.testing.assert_array_equal(sim.T_f_c, truth.T_f_c)
    assert [t.T_cf_t.tolist() for t in sim.targets] == [t.T_cf_t.tolist() for t in truth.targets]

    previous = [p for p in tmp_path.iterdir() if p.name != "cell.toml"]
    assert len(previous) == 1 and re.fullmatch(r"cell\.\d{8}T\d{6}Z\.previous\.toml", previous[0].name)
    assert previous[0].read_text() == before
    provenance = read_calibration_provenance(path)
    assert provenance is not None and provenance["previous"] == previous[0].name
    assert provenance["session"] == PROVENANCE["session"] and provenance["devices"] == PROVENANCE["devices"]
    assert provenance["sim"] is True and provenance["date"].startswith("20")
    assert provenance["steps"]["base"]["max_mm"] == 0.05 and provenance["steps"]["base"]["poses"] == 3
    assert provenance["steps"]["sfi"]["spread_mm_max"] == pytest.approx(3.1)
    assert provenance["steps"]["cell"]["truth_cell_mm"] == 0.011
    assert provenance["steps"]["intrinsics"] == {"done": "2025-06-01T10:00:00+00:00", "rms_px": 0.14, "images": 12,
                                                 "rejected": 1}


def test_the_template_gets_t_cf_si_for_poses_taught_as_flange_poses(tmp_path: Path) -> None:
    """The template's S1, S3, S4 give T_b_f only: T_cf_si is added to them; its comments stay; its
    [calibration] is replaced, keeping the summaries of the steps not written."""
    path = _copy(tmp_path, "cell-template.toml")
    before = path.read_text()
    steps = _steps(path, seed=5)
    write_calibration(path, steps, PROVENANCE)
    _assert_loads(path, steps)
    after = path.read_text()
    comments = [line for line in before.split("\n[calibration]")[0].splitlines() if line.lstrip().startswith("#")]
    assert [line for line in after.splitlines() if line in comments] == comments
    assert after.count("T_b_f = [  # REPLACE") == before.count("T_b_f = [  # REPLACE") == 2
    assert after.count("T_cf_si = [") == 4
    provenance = read_calibration_provenance(path)
    assert provenance["steps"]["accuracy"]["rms_dT_mm"] == 0.3  # kept from the template's [calibration]
    assert provenance["steps"]["sfi"]["poses"] == 4 and "camera" in provenance["devices"]


def test_a_file_that_would_not_load_is_refused_and_nothing_is_lost(tmp_path: Path) -> None:
    path = _copy(tmp_path, "sim-cell.toml")
    path.write_text(path.read_text().replace("grab_timeout_s = 2.0", "grab_timeout_s = 2.0\nexposur_us = 5.0"))
    broken = path.read_bytes()
    steps = _steps(CONFIG_DIR / "sim-cell.toml", seed=3)
    with pytest.raises(CalibrationFileRefused, match=r"exposur_us.*did you mean 'exposure_us'") as raised:
        write_calibration(path, steps, PROVENANCE)
    assert raised.value.plc_code == 726 and str(path) in str(raised.value)
    assert path.read_bytes() == broken and [p.name for p in tmp_path.iterdir()] == ["cell.toml"]

    path.write_text((CONFIG_DIR / "sim-cell.toml").read_text())
    good = path.read_bytes()
    bad = dict(steps, base=dict(steps["base"], T_cf_b=(2.0 * np.eye(4)).tolist()))
    with pytest.raises(CalibrationValueInvalid, match="T_cf_b"):
        write_calibration(path, bad, PROVENANCE)
    unknown = dict(steps, sfi=dict(steps["sfi"], poses=[dict(steps["sfi"]["poses"][0], name="S9")]))
    with pytest.raises(CalibrationValueInvalid, match="S9"):
        write_calibration(path, unknown, PROVENANCE)
    with pytest.raises(CalibrationValueInvalid, match="operator"):
        write_calibration(path, steps, PROVENANCE | {"operator": "me"})
    assert path.read_bytes() == good and [p.name for p in tmp_path.iterdir()] == ["cell.toml"]


def test_two_writes_keep_two_previous_files_and_untouched_steps(tmp_path: Path) -> None:
    path = _copy(tmp_path, "sim-cell.toml")
    original = path.read_text()
    first, second = _steps(path, seed=1), _steps(path, seed=2)
    write_calibration(path, first, PROVENANCE)
    after_first = path.read_text()
    write_calibration(path, {"base": second["base"]}, PROVENANCE | {"sim": False})  # only the base again

    previous = sorted(p for p in tmp_path.iterdir() if p.name != "cell.toml")
    assert len(previous) == 2
    assert {p.read_text() for p in previous} == {original, after_first}
    provenance = read_calibration_provenance(path)
    assert provenance["previous"] != tomllib.loads(after_first)["calibration"]["previous"]
    assert (tmp_path / provenance["previous"]).read_text() == after_first
    assert provenance["sim"] is False and set(provenance["steps"]) == {"intrinsics", "cell", "base", "part", "sfi"}
    expected = dict(first, base=second["base"])  # the other steps' values are those of the first write
    _assert_loads(path, expected)
    assert path.read_text().count("[calibration]") == 1


def test_a_failed_accuracy_validation_keeps_the_calibration_out_unless_accepted(tmp_path: Path) -> None:
    """`monoguide calibrate` after the last step: a FAILED Table-3 verdict writes the report but not the cell
    config (nothing changes, no previous copy); `--accept` writes it."""
    config = _copy(tmp_path, "sim-cell.toml")
    before = config.read_text()
    session, _ = open_session(tmp_path / "work", config, False, {})
    steps = _steps(config, 5)
    row = {"lt": [0.1, 0.2, 0.3, 10.0, 20.0, 30.0], "mono": [0.1, 0.2, 0.3, 10.0, 20.0, 30.9],
           "delta": [0.0, 0.0, 0.0, 0.0, 0.0, 0.9], "dR_deg": 0.0, "dT_mm": 0.9, "dT_grasp_mm": 0.9}
    steps["accuracy"] = {"rows": [row], "rms_dR_deg": 0.0, "rms_dT_mm": 0.9, "rms_dT_grasp_mm": 0.9, "passed": False,
                         "tolerance_mm": 0.5, "tolerance_deg": 0.05, "markdown": "| LT | ... |"}
    for name, result in steps.items():
        session.record_result(name, result)
    assert write_results(session, config, tmp_path / "work", False) is False
    assert config.read_text() == before and not list(tmp_path.glob("*.previous.toml"))
    assert "calibration_file" not in session.data and (tmp_path / "work" / "calibration-report.md").exists()
    assert write_results(session, config, tmp_path / "work", False, accept=True) is True
    _assert_loads(config, steps)
    assert len(list(tmp_path.glob("*.previous.toml"))) == 1


# --- the document writer against the text-level editor it replaced ---------------------------------


def _template_without_part_provenance() -> str:
    """The template without its [calibration.parts.2] example: yesterday's text editor, the writer's reference
    here, knew no part types (the writer's keeping of them: tests/daemon/calibrate/test_part_types.py)."""
    text = (CONFIG_DIR / "cell-template.toml").read_text()
    example = r"\n# A cell of several part types \(\[\[parts\]\], below\) only:.*?(?=\n# --- several part types)"
    cut = re.sub(example, "\n", text, count=1, flags=re.S)
    assert "[calibration.parts" not in cut
    return cut


def _template_with_added_keys_and_a_table_after_calibration() -> str:
    """The template without [reference] T_cf_b and [camera] T_f_c (the writer adds them where the comments that
    introduce the next table do not stand), with comments after a matrix's opening bracket and after a value,
    and [tracker] moved after [calibration] below a comment of its own."""
    text = _template_without_part_provenance()
    text = re.sub(r"# the robot base in the cell frame .*?\n\]\n", "", text, count=1, flags=re.S)
    text = re.sub(r"# the calibrated camera mounting on the flange.*?\n\]\n", "", text, count=1, flags=re.S)
    text = re.sub(r"(T_cf_si = \[)\n", r"\1  # from the last calibration\n", text, count=1)
    text = re.sub(r"^(height = \d+)$", r"\1  # px", text, count=1, flags=re.M)
    tracker = re.search(r"^\[tracker\].*?\n\n", text, flags=re.S | re.M)
    assert tracker and "T_cf_b = [" not in text and "T_f_c = [" not in text
    return text.replace(tracker.group(0), "") + "\n# the tracker the cell was measured with\n" + tracker.group(0)


COMPARED = {
    "sim-cell": lambda: (CONFIG_DIR / "sim-cell.toml").read_text(),
    "cell-template": _template_without_part_provenance,
    "template, keys added, a table after [calibration]": _template_with_added_keys_and_a_table_after_calibration,
}


@pytest.mark.parametrize("case", list(COMPARED))
def test_the_document_writer_keeps_what_the_text_editor_kept(tmp_path: Path, case: str) -> None:
    """Today's writer (tomlkit) and yesterday's text-level editor (calibration_text_editor.py), fed the same
    values: both files load to the same keys in the same order and the same values (matrices within 1e-9), and
    hold the same comments in the same order — but for the comments that introduced a [calibration.*] table,
    which the text editor left stranded below the new section and the writer replaces with the section."""
    text = COMPARED[case]()
    source = CONFIG_DIR / ("sim-cell.toml" if case == "sim-cell" else "cell-template.toml")
    steps = _steps(source, seed=21)
    provenance = PROVENANCE | {"date": "2025-07-01T08:00:00+00:00"}
    path = tmp_path / "cell.toml"
    path.write_text(text)
    write_calibration(path, steps, provenance)
    written = path.read_text()
    raw = tomllib.loads(text)
    record = _provenance(steps, provenance, raw, tomllib.loads(written)["calibration"]["previous"], datetime.now(UTC))
    edited = edit_calibration_text(text, _calibrated_values(steps, raw, path), record, path)

    new, old = _entries(tomllib.loads(written)), _entries(tomllib.loads(edited))
    assert [where for where, _ in new] == [where for where, _ in old]
    for (where, a), (_, b) in zip(new, old, strict=True):
        if isinstance(a, list) and a and all(isinstance(v, int | float | list) for v in a):
            np.testing.assert_allclose(np.asarray(a, dtype=float), np.asarray(b, dtype=float), rtol=0, atol=1e-9,
                                       err_msg=where)
        else:
            assert a == b, where
    _assert_loads(path, steps)

    introducing = {line for line in _comment_blocks_above(text, "[calibration.")}
    assert introducing or case == "sim-cell"
    assert _comments(written) == [c for c in _comments(edited) if c not in introducing]
    kept = [c for c in _comments(text.split("\n[calibration]")[0])]
    assert kept and _comments(written)[:len(kept)] == kept  # what stood before the section, in order
    if case.startswith("template, keys"):
        assert re.search(r"\n\]\nT_cf_b = \[\n(.*\n){4}\]\n\n# One \[\[measuring_poses\]\]", written)
        assert re.search(r"\n# the tracker the cell was measured with\n\n?\[tracker\]", written)


def _inline_tables() -> str:
    """The simulated cell with [camera.intrinsics] as an inline table and the measuring poses as an inline array
    of tables before the first header."""
    doc = tomlkit.parse((CONFIG_DIR / "sim-cell.toml").read_text())
    intrinsics = tomlkit.inline_table()
    intrinsics.update(doc["camera"]["intrinsics"].unwrap())
    del doc["camera"]["intrinsics"]
    doc["camera"]["intrinsics"] = intrinsics
    poses = tomlkit.array()
    for pose in doc["measuring_poses"].unwrap():
        entry = tomlkit.inline_table()
        entry.update(pose)
        poses.append(entry)
    del doc["measuring_poses"]
    return "measuring_poses = " + poses.as_string() + "  # inline\n\n" + doc.as_string()


def _out_of_order() -> str:
    """The simulated cell with [camera.intrinsics] at the end, away from [camera], and no [camera] T_f_c."""
    text = (CONFIG_DIR / "sim-cell.toml").read_text()
    intrinsics = re.search(r"^\[camera\.intrinsics\].*?\n\n", text, flags=re.S | re.M).group(0)
    T_f_c = re.search(r"^T_f_c = \[\n(.*\n){4}\]\n", text, flags=re.M).group(0)
    return text.replace(intrinsics, "").replace(T_f_c, "", 1) + "\n" + intrinsics


@pytest.mark.parametrize("layout", [_inline_tables, _out_of_order])
def test_tables_written_inline_or_out_of_order_are_edited(tmp_path: Path, layout: Any) -> None:
    """Where the old text editor refused (CALIBRATION_FILE_UNEDITABLE), the document writer calibrates; the
    simulated truth and every other value stay as they were."""
    text = layout()
    path = tmp_path / "cell.toml"
    path.write_text(text)
    steps = _steps(CONFIG_DIR / "sim-cell.toml", seed=8)
    write_calibration(path, steps, PROVENANCE)
    _assert_loads(path, steps)
    calibrated = {"intrinsics", "T_f_c", "T_cf_b", "T_cf_w0", "T_cf_si", "calibration"}
    before, after = tomllib.loads(text), tomllib.loads(path.read_text())
    assert _uncalibrated(after, calibrated) == _uncalibrated(before, calibrated)
    assert _comments(path.read_text())[:len(_comments(text))] == _comments(text)


def _uncalibrated(data: Any, calibrated: set[str]) -> Any:
    """The parsed file without the calibrated keys (the simulated truth's [sim] T_f_c is not one)."""
    if isinstance(data, dict):
        return {k: v if k == "sim" else _uncalibrated(v, calibrated) for k, v in data.items() if k not in calibrated}
    if isinstance(data, list):
        return [_uncalibrated(v, calibrated) for v in data]
    return data


@pytest.mark.parametrize(("text", "match"), [
    (b"[camera\nbackend = 'sim'\n", "not valid TOML"),
    (b"\xff\xfe[camera]\n", "not valid TOML"),
    (b"camera = 5\n[reference]\nT_cf_w0 = []\n", r"no \[camera.intrinsics\]"),
])
def test_a_file_the_calibration_cannot_go_into_is_uneditable(tmp_path: Path, text: bytes, match: str) -> None:
    path = tmp_path / "cell.toml"
    path.write_bytes(text)
    with pytest.raises(CalibrationFileUneditable, match=match) as raised:
        write_calibration(path, {"intrinsics": _steps(CONFIG_DIR / "sim-cell.toml", seed=4)["intrinsics"]},
                          PROVENANCE)
    assert raised.value.plc_code == 728
    assert path.read_bytes() == text and [p.name for p in tmp_path.iterdir()] == ["cell.toml"]


def test_the_file_keeps_its_mode_and_a_failed_write_leaves_it_alone(tmp_path: Path,
                                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    path = _copy(tmp_path, "sim-cell.toml")
    path.chmod(0o640)
    before = path.read_bytes()
    steps = _steps(path, seed=9)

    def disk_full(fd: int) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    with monkeypatch.context() as patch:
        patch.setattr(atomic_file.os, "fsync", disk_full)
        with pytest.raises(CalibrationFileError, match="No space left") as raised:
            write_calibration(path, steps, PROVENANCE)
    assert raised.value.plc_code == 725
    assert path.read_bytes() == before and [p.name for p in tmp_path.iterdir()] == ["cell.toml"]

    write_calibration(path, steps, PROVENANCE)
    previous = tmp_path / read_calibration_provenance(path)["previous"]
    assert previous.read_bytes() == before
    assert stat.S_IMODE(path.stat().st_mode) == stat.S_IMODE(previous.stat().st_mode) == 0o640
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["cell.toml", previous.name])


def _entries(data: Any, where: str = "") -> list[tuple[str, Any]]:
    """(dotted key, value) of every value in the parsed file, in the file's order (tables as their keys)."""
    if isinstance(data, dict):
        return [e for key, value in data.items() for e in _entries(value, f"{where}.{key}" if where else key)]
    if isinstance(data, list) and data and all(isinstance(v, dict) for v in data):
        return [e for i, value in enumerate(data) for e in _entries(value, f"{where}[{i}]")]
    return [(where, data)]


def _comments(text: str) -> list[str]:
    """Every comment of a TOML text in order (whole-line ones and those after a value), outside strings."""
    out = []
    for line in text.splitlines():
        quote = None
        for i, c in enumerate(line):
            if quote and c == "\\" and quote == '"':
                continue
            if quote:
                quote = None if c == quote and line[i - 1] != "\\" else quote
            elif c in "\"'":
                quote = c
            elif c == "#":
                out.append(line[i:].strip())
                break
    return out


def _comment_blocks_above(text: str, header: str) -> list[str]:
    """The comment lines directly above each header line starting with ``header``."""
    lines, out = text.splitlines(), []
    for i, line in enumerate(lines):
        if line.startswith(header):
            k = i
            while k > 0 and lines[k - 1].lstrip().startswith("#"):
                k -= 1
            out += [c.strip() for c in lines[k:i]]
    return out
