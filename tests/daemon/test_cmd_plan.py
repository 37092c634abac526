"""`monoguide plan` through the CLI."""

import json
from pathlib import Path

import cv2
from typer.testing import CliRunner

from monoguide.daemon.cli import app

EXAMPLE = Path(__file__).parents[2] / "examples" / "example-record.json"


def test_plan_writes_the_map_and_reports_a_layout(tmp_path):
    out = tmp_path / "fig5.png"
    run = CliRunner().invoke(app, ["plan", "--json", "--steps", "6", "--out", str(out), "--record", str(EXAMPLE)])
    assert run.exit_code == 0, run.output
    report = json.loads(run.stdout)
    image = cv2.imread(str(out))
    assert image is not None and image.shape[0] > 200 and image.shape[1] > 200
    assert len(report["recommended_pixels"]) == 4
    # the example record places its holes like the plan does: 0.1 px gives about 0.1 mm
    assert 0.05 < report["record"]["sigma_trans_mm"] < 0.15
    assert 0.05 < report["recommended"]["sigma_trans_mm"] < 0.15


def test_plan_reports_a_bad_record(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text('{"format": "nope"}')
    run = CliRunner().invoke(app, ["plan", "--steps", "3", "--record", str(bad)])
    assert run.exit_code == 0
    assert "RECORD_FORMAT" in run.stdout
