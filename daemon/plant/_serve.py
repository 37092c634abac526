"""``monoguide plant`` running: the OPC UA server and the metrics endpoint fed by one loop that reads the cell's
state directory every ``[plant] poll_s`` (docs/opcua.md, docs/metrics.md).

Its own process beside the service: it listens on sockets the service must never open (DESIGN: ``monoguide run``
listens on none), it can be restarted, crash or be firewalled without touching the cell, and the cell's cycle never
waits for it — it only reads the journal and ``status.json``, read-only.
"""

from __future__ import annotations

import asyncio
import contextlib
import datetime
import hashlib
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from monoguide.daemon.plant._address_space import CellDescription, Recipe
from monoguide.daemon.plant._cell_view import CellView
from monoguide.daemon.plant._metrics import PlantMetrics
from monoguide.daemon.plant._metrics_http import MetricsEndpoint
from monoguide.daemon.plant._opcua import PlantOpcUa
from monoguide.daemon.plant._pki import ServerIdentity
from monoguide.daemon.plant._refusals import Refusals
from monoguide.daemon.plant._result_data import Configuration
from monoguide.daemon.plant._settings import PlantSettings

log = logging.getLogger(__name__)

DEFAULT_PART_NAME = "part"
SLOW_POLL_S = 1.0  # a poll slower than this is logged


@dataclass(frozen=True)
class PlantEndpoints:
    """Where the plant serves, said once it listens."""

    opcua_url: str
    metrics_url: str
    identity: ServerIdentity


def describe_cell(config: Any, last_results: int, config_path: Path | None = None) -> CellDescription:
    """The recipes (job number, part name) and the calibration date of a loaded cell config: every part type of
    ``config.parts`` when the config has them, else its one part as job 1; with ``config_path`` the file's SHA-256
    and time of change (the configuration's id in OPC UA)."""
    parts = tuple(getattr(config, "parts", ()) or ())
    recipes = tuple(Recipe(int(p.job), str(p.name)) for p in parts)
    if not recipes:
        recipes = (Recipe(1, str(getattr(config.part, "name", None) or DEFAULT_PART_NAME)),)
    robot = getattr(config, "robot", None)
    simulated = config.camera.backend == "sim" or bool(robot is not None and robot.simulated)
    date = (config.calibration or {}).get("date")
    digest, modified = None, None
    if config_path is not None:
        digest = hashlib.sha256(config_path.read_bytes()).digest()
        modified = config_path.stat().st_mtime
    configuration = Configuration(str(config.name), None if date is None else str(date), digest)
    return CellDescription(config.name, recipes, calibration_date(config.calibration), simulated, last_results,
                           configuration, modified)


def calibration_date(provenance: dict[str, Any] | None) -> float | None:
    """``[calibration] date`` (ISO 8601, written by `monoguide calibrate`) as Unix s; None when absent or unreadable."""
    date = (provenance or {}).get("date")
    try:
        parsed = datetime.datetime.fromisoformat(str(date))
    except ValueError:
        return None
    if parsed.tzinfo is None:
        parsed = parsed.astimezone()  # a local time, as the wizard writes it without an offset
    return parsed.timestamp()


async def serve_plant(config: Any, settings: PlantSettings, state_dir: Path, stop: asyncio.Event,
                      on_ready: Callable[[PlantEndpoints], None] | None = None,
                      config_path: Path | None = None) -> None:
    """Serve until ``stop`` is set. Raises :class:`PlantListenFailed`, :class:`PlantCertificateError`,
    :class:`PlantNodeSetInvalid`."""
    cell = describe_cell(config, settings.last_results, config_path)
    view = CellView(state_dir)
    refusals = Refusals(settings.limits.refusal_log_s)
    metrics = PlantMetrics(cell.calibration_date)
    endpoint = MetricsEndpoint(metrics.registry, settings.metrics_access, settings.limits, refusals)
    opcua = PlantOpcUa(settings, state_dir, cell, refusals)
    try:
        metrics_url = await endpoint.start(settings.metrics_host, settings.metrics_port)
        identity = await opcua.start()
        # the journal is read in a worker thread: a read that waits on SQLite (a checkpoint of the service's WAL,
        # a busy file) must never hold up the OPC UA server's loop and its clients' requests
        newest, counts = await asyncio.to_thread(view.start, settings.last_results)
        metrics.seed(counts, newest, view.seen)
        await opcua.seed(newest)
        await _show(view, opcua, metrics)  # the first reading before anyone is told we serve: no empty first answer
        if on_ready is not None:
            on_ready(PlantEndpoints(opcua.url, metrics_url, identity))
        while not stop.is_set():
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(stop.wait(), settings.poll_s)
            if not stop.is_set():
                await _show(view, opcua, metrics)
                refusals.tick()
                metrics.count_refusals(refusals.total)
    finally:
        await opcua.stop()
        await endpoint.stop()
        view.close()


async def _show(view: CellView, opcua: PlantOpcUa, metrics: PlantMetrics) -> None:
    """One reading of the state directory, shown in the address space and the metrics."""
    started = time.monotonic()
    reading = await asyncio.to_thread(view.poll)
    if time.monotonic() - started > SLOW_POLL_S:
        log.warning("reading the state directory took %.1f s", time.monotonic() - started)
    await opcua.show(reading)
    metrics.show(reading)
