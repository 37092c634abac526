"""The simulated part supply draws inside each part type's envelope, as the envelope defines it: the same parts
as the cell's own draw with the same seed, none refused by the offset check, and a type's own envelope kept."""

import json
from pathlib import Path

import numpy as np
from helpers.envelope_jobs import EnvelopeJob, refusal
from helpers.repository import SIM_CELL

from monoguide.daemon.assembly import build_sim_cell
from monoguide.daemon.config import load_cell_config
from monoguide.drivers.sim.cell import deviated_part
from monoguide.drivers.sim.part_supply import PART_STREAM, PartSupply
from monoguide.solver import frames
from monoguide.solver.envelope import DeviationEnvelope, deviation_about


def _spec(tmp_path: Path) -> tuple[dict, Path]:
    cfg = load_cell_config(SIM_CELL)
    spec = build_sim_cell(cfg).write_robot_spec(tmp_path / "robot.json", part_types=cfg.jobs)
    return json.loads(spec.read_text()), spec


def test_the_supply_presents_the_cells_own_seeded_draw_of_each_type(tmp_path: Path) -> None:
    """Ground truth: ``drivers.sim.cell.deviated_part`` with the supply's seed stream, about each type's centroid."""
    data, spec = _spec(tmp_path)
    supply = PartSupply.from_spec_file(spec, None)
    for part in range(1, 7):
        T_b_w = supply.arrive()
        kind = supply.types[supply.job] if supply.types else data["part_supply"]
        rng = np.random.default_rng([data["seed"], PART_STREAM, part])
        expected = deviated_part(rng, np.array(kind["T_cf_w0"]), np.array(kind["centre_w"]),
                                 data["part_supply"]["translation_mm"], data["part_supply"]["rotation_deg"])
        np.testing.assert_allclose(supply.T_cf_b @ T_b_w, expected, atol=1e-9)


def test_no_part_the_supply_presents_is_refused_by_the_envelope_it_was_drawn_in(tmp_path: Path) -> None:
    data, spec = _spec(tmp_path)
    supply = PartSupply.from_spec_file(spec, None)
    s = data["part_supply"]
    envelope = DeviationEnvelope(tuple(s["translation_mm"]), tuple(s["rotation_deg"]))
    for _ in range(200):
        T_cf_w = supply.T_cf_b @ supply.arrive()
        kind = supply.types[supply.job] if supply.types else s
        T_cf_w0 = np.array(kind["T_cf_w0"])
        job = EnvelopeJob(supply.job, "", np.array([kind["centre_w"]]), np.array(kind["centre_w"]), T_cf_w0,
                          T_cf_w0, envelope.at(np.array([kind["centre_w"]])))
        assert refusal(job, frames.invert(T_cf_w0) @ T_cf_w) is None


def test_a_type_with_an_envelope_of_its_own_is_drawn_inside_it(tmp_path: Path) -> None:
    data, _ = _spec(tmp_path)
    s = data["part_supply"]
    kinds = s.get("types") or [{"job": 1, "T_cf_w0": s["T_cf_w0"], "first_pose": 1, "T_b_w0": data["T_b_w0"],
                                "T_b_g0": data["T_b_g0"]}]
    own = {**kinds[0], "about_w": [10.0, 20.0, 30.0], "translation_mm": [5.0, 5.0, 5.0],
           "rotation_deg": [1.0, 1.0, 1.0], "total_mm": 6.0, "total_deg": 1.2}
    supply = PartSupply(data["seed"], {**s, "types": [own], "sequence": [own["job"]]}, np.array(data["T_b_g0"]), None)
    T_cf_w0 = np.array(own["T_cf_w0"])
    for _ in range(100):
        T_w0_w = frames.invert(T_cf_w0) @ supply.T_cf_b @ supply.arrive()
        rotation, shift = deviation_about(T_w0_w, np.array(own["about_w"]))
        assert np.all(np.abs(shift) <= 5.0) and np.linalg.norm(shift) <= 6.0
        assert np.all(np.abs(rotation) <= 1.0) and np.linalg.norm(rotation) <= 1.2
