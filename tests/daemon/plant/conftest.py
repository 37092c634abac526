"""``monoguide plant`` as its own process on a seeded state directory, one per test module (its ``HOST``, ``PORT``)."""

from __future__ import annotations

import time
from collections.abc import Iterator

import pytest
from helpers.plant_cells import PlantCell, StatusBeat, plant_file, seeded_entries, write_journal
from helpers.plant_clients import client_identity, start_plant, trust
from helpers.repository import SIM_CELL
from helpers.sim_processes import stop


@pytest.fixture(scope="module")
def plant_cell(tmp_path_factory: pytest.TempPathFactory, request: pytest.FixtureRequest) -> Iterator[PlantCell]:
    """One plant process on a seeded state directory, at the module's ``HOST``, ``PORT``."""
    host, port = request.module.HOST, request.module.PORT
    tmp = tmp_path_factory.mktemp("plant")
    state_dir = tmp / "state"
    seeded = seeded_entries(12, time.time() - 3600.0)
    write_journal(state_dir, seeded)
    beat = StatusBeat(state_dir)
    client, stranger = client_identity(tmp / "clients", "scada-client"), client_identity(tmp / "clients", "stranger")
    trust(client, state_dir / "plant" / "trusted")
    log = tmp / "plant.log"
    process, line = start_plant(SIM_CELL, state_dir, plant_file(tmp / "plant.toml", host, port), log)
    words = line.split()
    try:
        yield PlantCell(state_dir, words[2], words[4], line, client, stranger, seeded, log, beat)
    finally:
        stop(process)
        beat.stop()
