"""The config's envelope keys give each part one envelope: ``[layout]`` per axis and its point
(``envelope_centre_w``, the envelope's ``about_w``), ``[checks]`` the totals and, when set, other per-axis limits."""

from pathlib import Path

import numpy as np
import pytest
from helpers.repository import SIM_CELL

from monoguide.daemon.config import load_cell_config
from monoguide.daemon.config._service import ChecksConfig
from monoguide.solver.envelope import DeviationEnvelope


def _with(tmp_path: Path, layout: str = "", checks: str = "") -> Path:
    text = SIM_CELL.read_text()
    text = text.replace("[layout]  #", f"[layout]\n{layout}\n#", 1)
    assert text.count("\n[checks]") == 1
    text = text.replace("\n[checks]", f"\n[checks]\n{checks}\n#", 1)
    path = tmp_path / "cell.toml"
    path.write_text(text)
    return path


def test_without_checks_the_envelope_is_the_layouts_with_the_norms_as_totals(tmp_path: Path) -> None:
    cfg = load_cell_config(_with(tmp_path, layout="envelope_centre_w = [600.0, 1000.0, 0.0]"))
    envelope = (cfg.checks or ChecksConfig()).envelope(cfg.layout.envelope)
    assert envelope == DeviationEnvelope((50.0, 50.0, 50.0), (5.0, 5.0, 5.0), (600.0, 1000.0, 0.0))
    assert envelope.limit_mm == pytest.approx(np.sqrt(3 * 50.0**2)) and envelope.limit_deg == pytest.approx(
        np.sqrt(3 * 5.0**2))
    # no [layout] either: +-50 mm / +-5 deg about the holes' centroid
    assert ChecksConfig().envelope(None) == DeviationEnvelope()


def test_checks_set_the_totals_and_may_narrow_an_axis(tmp_path: Path) -> None:
    cfg = load_cell_config(_with(tmp_path, checks="envelope_mm = 60.0\nenvelope_deg = 6.0\n"
                                                   "envelope_axis_mm = [50.0, 50.0, 10.0]"))
    envelope = cfg.checks.envelope(cfg.layout.envelope)
    assert envelope == DeviationEnvelope((50.0, 50.0, 10.0), (5.0, 5.0, 5.0), None, 60.0, 6.0)
    points = np.asarray(cfg.part.points_w)
    np.testing.assert_allclose(envelope.at(points).about_w, points.mean(axis=0))
