"""The plant beside a real service: `monoguide sim-cell` (its PLC plays the parts) and `monoguide run` running cycles,
`monoguide plant` reading their state directory, the asyncua client subscribed to the result events and reading the
state while the cycles run. Each event carries the journal's values; its offset equals the journal's (and what the
PLC was given) to float32 precision."""

from __future__ import annotations

import asyncio
import contextlib
import sys
from pathlib import Path

import numpy as np
import pytest
from asyncua import ua
from helpers.cell_configs import cell_config
from helpers.plant_cells import PASSWORD, USER, plant_file
from helpers.plant_clients import (
    NAMESPACE,
    client_identity,
    connected,
    load_machine_vision_types,
    start_plant,
    subscribe_results,
    trust,
    value,
)
from helpers.sim_processes import keep_reading, start_sim_cell, stop

from monoguide.daemon.service import Journal

ROBOT_HOST, PLC_HOST, PLANT_HOST, PLANT_PORT = "127.0.83.10", "127.0.83.11", "127.0.83.12", 48301
CYCLES = 3


@pytest.mark.slow
def test_events_and_state_while_the_service_runs(tmp_path: Path) -> None:
    config = cell_config(tmp_path, ROBOT_HOST, PLC_HOST, sharp=True, state_file=tmp_path / "sim-state.json")
    state_dir = tmp_path / "state"
    state_dir.mkdir()
    client_id = client_identity(tmp_path / "clients", "mes")
    trust(client_id, state_dir / "plant" / "trusted")
    plant, line = start_plant(config, state_dir, plant_file(tmp_path / "plant.toml", PLANT_HOST, PLANT_PORT),
                              tmp_path / "plant.log")
    sim = None
    try:
        async def run() -> tuple[list, set[str]]:
            nonlocal sim
            client = await connected(line.split()[2], client_id, user=USER, password=PASSWORD)
            try:
                await load_machine_vision_types(client)
                log, _ = await subscribe_results(client)
                idx = await client.get_namespace_index(NAMESPACE)
                machine = client.get_node(ua.NodeId("VisionSystem.VisionStateMachine", idx))
                current = await machine.get_child("0:CurrentState")
                seen = {(await current.read_value()).Text}
                sim, _ = start_sim_cell(config, "--parts", str(CYCLES))
                keep_reading(sim)
                service = await asyncio.create_subprocess_exec(
                    sys.executable, "-m", "monoguide.daemon.cli", "run", "--config", str(config), "--state-dir",
                    str(state_dir), "--cycles", str(CYCLES), stdout=asyncio.subprocess.DEVNULL,
                    stderr=asyncio.subprocess.DEVNULL)
                try:
                    while service.returncode is None and len(log.events) < CYCLES:
                        seen.add((await current.read_value()).Text)
                        await asyncio.sleep(0.05)
                        if service.returncode is None:
                            with contextlib.suppress(TimeoutError):
                                await asyncio.wait_for(service.wait(), 0.001)
                    await log.wait_for(CYCLES, 60.0)
                    assert await asyncio.wait_for(service.wait(), 60.0) == 0
                finally:
                    if service.returncode is None:
                        service.kill()
                        await service.wait()
                await asyncio.sleep(3.5)  # the service's status file goes stale: Halted
                seen.add((await current.read_value()).Text)
                return log.events, seen
            finally:
                await client.disconnect()

        events, seen = asyncio.run(run())
    finally:
        if sim is not None:
            stop(sim)
        stop(plant)
    assert {"Operational", "Halted"} <= seen, seen
    with Journal(state_dir, read_only=True) as journal:
        rows = journal.last_cycles(CYCLES)[::-1]
    assert [value(fields, "ResultId").Id for _, fields in events] == [str(row.number) for row in rows]
    for (arrived, fields), row in zip(events, rows, strict=True):
        assert value(fields, "Status") == row.status == "ok", row.error_message
        assert value(fields, "PartTag") == row.part_tag and value(fields, "Job") == row.job
        offset = np.array(value(fields, "BaseOffset"), dtype=np.float32)
        assert np.array_equal(offset, np.array(row.result["base_offset_xyzabc"], dtype=np.float32))
        assert value(fields, "RmsPx") == pytest.approx(row.result["rms_px"], rel=1e-6)
        assert value(fields, "SigmaPositionMm") == pytest.approx(row.result["sigma_trans_mm"], rel=1e-6)
        assert value(fields, "CycleTime") == pytest.approx(row.timings_s["cycle"])
        times = value(fields, "ProcessingTimes")  # OPC 40100: the trigger's time is the result's StartTime
        assert times.StartTime.timestamp() == pytest.approx(row.started_at, abs=1e-3)
        assert arrived - row.finished_at < 2.0
