"""`monoguide solve` end to end through the CLI, on synthetic records with known truth."""

import json
from pathlib import Path

import numpy as np
from typer.testing import CliRunner

from monoguide.daemon.cli import app
from monoguide.solver import frames
from monoguide.solver.synthetic import deviated_part, paper_roof_cell

EXAMPLE = Path(__file__).parents[2] / "examples" / "example-record.json"
SPEC_FIELDS = {"id", "status", "T_s1_w", "offset", "rms_px", "covariance", "sigma_rot_deg", "sigma_trans_mm",
               "method", "iterations", "time_ms"}


def _synthetic_record(rng, record_id):
    cell = paper_roof_cell()
    T_true = deviated_part(cell, rng, 4.0, 40.0)
    pixels = cell.project(T_true) + rng.normal(0, 0.1, (4, 2))
    record = {
        "format": "monoguide.measurement/1",
        "id": record_id,
        "camera": cell.camera.as_dict(),
        "points_w": cell.points_w.tolist(),
        "views": [{"T_s1_si": T.tolist()} for T in cell.T_s1_si],
        "T_s1_w0": cell.T_s1_w0.tolist(),
        "observations": [
            {"view": v, "point": p, "pixel": pixels[j].tolist()} for j, (v, p) in enumerate(cell.observed)
        ],
        "sigma_px": 0.1,
    }
    return record, T_true


def test_jsonl_batch_goes_on_past_bad_records(tmp_path):
    rng = np.random.default_rng(41)
    good, truths = [], {}
    for k in range(3):
        record, T_true = _synthetic_record(rng, f"part-{k}")
        good.append(json.dumps(record))
        truths[f"part-{k}"] = T_true
    bad_format = json.dumps({"format": "other/1", "id": "wrong"})
    lines = [good[0], bad_format, "{not json", good[1], "", good[2]]
    path = tmp_path / "batch.jsonl"
    path.write_text("\n".join(lines) + "\n")
    run = CliRunner().invoke(app, ["solve", "--json", str(path)])
    assert run.exit_code == 1, run.output
    results = [json.loads(line) for line in run.stdout.splitlines()]
    assert [r["status"] for r in results] == ["ok", "error", "error", "ok", "ok"]
    assert results[1]["error"]["code"] == "RECORD_FORMAT" and results[1]["id"] == "wrong"
    assert results[2]["error"]["code"] == "RECORD_INVALID" and "line 3" in results[2]["error"]["message"]
    for result in (results[0], results[3], results[4]):
        assert set(result) == SPEC_FIELDS
        d_rot, d_mm = frames.pose_difference(np.array(result["T_s1_w"]), truths[result["id"]])
        assert d_rot < 0.05 and d_mm < 0.6


def test_human_table_and_stdin(tmp_path):
    run = CliRunner().invoke(app, ["solve", "-"], input=EXAMPLE.read_text())
    assert run.exit_code == 0, run.output
    assert "example-1" in run.stdout and "vs truth" in run.stdout


def test_paper_method_and_unknown_method():
    run = CliRunner().invoke(app, ["solve", "--json", "--method", "paper", str(EXAMPLE)])
    assert run.exit_code == 0 and json.loads(run.stdout)["method"] == "paper"
    run = CliRunner().invoke(app, ["solve", "--method", "magic", str(EXAMPLE)])
    assert run.exit_code != 0 and "magic" in run.output


def test_missing_file_is_an_error_line_not_a_traceback(tmp_path):
    run = CliRunner().invoke(app, ["solve", "--json", str(tmp_path / "nope.json"), str(EXAMPLE)])
    assert run.exit_code == 1
    first, second = (json.loads(line) for line in run.stdout.splitlines())
    assert first["status"] == "error" and "cannot read" in first["error"]["message"]
    assert second["status"] == "ok"


def test_robust_only_with_the_ml_estimator():
    run = CliRunner().invoke(app, ["solve", "--robust", "--method", "paper", str(EXAMPLE)])
    assert run.exit_code != 0 and "Huber" in run.output
    run = CliRunner().invoke(app, ["solve", "--json", "--robust", str(EXAMPLE)])
    assert run.exit_code == 0 and json.loads(run.stdout)["method"] == "ml-huber"
