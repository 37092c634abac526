"""The simulated cell of config/sim-cell.toml, in this process: the one truth its simulated devices read."""

from __future__ import annotations

from helpers.repository import SIM_CELL
from monoguide.daemon.assembly import build_sim_cell
from monoguide.daemon.config import load_cell_config
from monoguide.drivers.sim.cell import SimCell


def new_sim_cell() -> SimCell:
    """A fresh simulated cell of config/sim-cell.toml (seeded by its ``[sim] seed``: every fresh one is the same)."""
    return build_sim_cell(load_cell_config(SIM_CELL))


def deviated_sim_cell() -> SimCell:
    """A fresh simulated cell whose part has arrived deviated: the ideal offset is not the identity."""
    cell = new_sim_cell()
    cell.new_part()
    return cell
